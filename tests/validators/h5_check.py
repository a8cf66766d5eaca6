#!/usr/bin/env python3
"""Reads an HDF5 file with h5py (the reference client) and prints a JSON
summary that knitvox's tests compare with what they wrote.

Usage: h5_check.py FILE

Output: {"attrs": {...root attributes...},
         "datasets": {"/path": {"shape", "dtype", "chunks", "compression",
                                "compression_opts", "shuffle", "attrs",
                                "checksum", "first_bits"}}}

Floats are compared exactly through their IEEE-754 bit patterns: "checksum"
is sum_i (i + 1) * bits(x_i) mod 2**64 over the values in C order (each value
converted to float64, integers to uint64), "first_bits" the bit patterns of
the first 6 values. This avoids any decimal round trip.
"""
import json
import sys

import h5py
import numpy as np


def plain(v):
    """An attribute value as JSON."""
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray):
        return [plain(x) for x in v.tolist()]
    if isinstance(v, np.generic):
        return plain(v.item())
    return v


def bits_of(arr):
    a = np.ascontiguousarray(arr).reshape(-1)
    if a.dtype.kind == "f":
        return a.astype("<f8").view("<u8")
    if a.dtype.kind in "iub":
        return a.astype("<u8")
    return None


def summary(ds):
    out = {
        "shape": list(ds.shape),
        "dtype": str(ds.dtype),
        "chunks": list(ds.chunks) if ds.chunks else None,
        "compression": ds.compression,
        "compression_opts": ds.compression_opts,
        "shuffle": bool(ds.shuffle),
        "attrs": {k: plain(v) for k, v in ds.attrs.items()},
    }
    bits = bits_of(ds[()]) if ds.size > 0 else np.zeros(0, dtype="<u8")
    if bits is not None:
        weights = np.arange(1, bits.size + 1, dtype="<u8")
        with np.errstate(over="ignore"):
            out["checksum"] = int((bits * weights).sum(dtype="<u8"))
        out["first_bits"] = [int(b) for b in bits[:6]]
    return out


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: h5_check.py FILE")
    datasets = {}
    with h5py.File(sys.argv[1], "r") as f:
        attrs = {k: plain(v) for k, v in f.attrs.items()}

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                datasets["/" + name] = summary(obj)

        f.visititems(visit)
    json.dump({"attrs": attrs, "datasets": datasets}, sys.stdout, sort_keys=True)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
