#!/usr/bin/env python3
"""Opens a .vtkhdf file with VTK's own vtkHDFReader (the reader ParaView uses)
and prints a JSON summary that knitvox's tests compare with what they wrote.

Usage: vtk_check.py FILE

Output: {"vtk_version", "number_of_steps", "time_values": [...],
         "steps": [{"step", "time", "points", "cells", "cell_types": [...distinct],
                    "all_tetra", "cell_arrays": [...], "point_arrays": [...],
                    "gamma_s", "mass", "point_bits": [...]}]}

A static file (no /VTKHDF/Steps) reports number_of_steps 1 (vtkHDFReader
counts it as one step), no time values and one entry in "steps". Each step is selected with vtkHDFReader.SetStep(i) before Update().
"point_bits" are the IEEE-754 bit patterns of every coordinate as float64,
in point order (x, y, z), so floats are compared exactly, with no decimal
round trip; "gamma_s" and "mass" are the bit patterns of those arrays.
Exits with status 1 (and a message on stderr) when VTK cannot read the file.
"""
import json
import sys

import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy


class ErrorObserver:
    """Collects VTK error events (VTK prints them and carries on otherwise)."""

    def __init__(self):
        self.messages = []

    def __call__(self, obj, event):
        self.messages.append(f"{obj.GetClassName()}: {event}")


def bits(arr):
    if arr is None:
        return None
    a = np.ascontiguousarray(vtk_to_numpy(arr), dtype="<f8").reshape(-1)
    return [int(b) for b in a.view("<u8")]


def main(path):
    vtk.vtkObject.GlobalWarningDisplayOff()
    reader = vtk.vtkHDFReader()
    errors = ErrorObserver()
    reader.AddObserver("ErrorEvent", errors)
    reader.GetExecutive().AddObserver("ErrorEvent", errors)
    if not reader.CanReadFile(path):
        print(f"vtkHDFReader cannot read {path}", file=sys.stderr)
        return 1
    reader.SetFileName(path)
    reader.UpdateInformation()
    n_steps = reader.GetNumberOfSteps()
    out_info = reader.GetOutputInformation(0)
    key = vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS()
    times = list(out_info.Get(key)) if out_info.Has(key) else []
    steps = []
    for s in range(max(n_steps, 1)):
        reader.SetStep(s)
        reader.Update()
        if errors.messages:
            print(f"step {s}: {errors.messages}", file=sys.stderr)
            return 1
        grid = reader.GetOutput()
        if grid is None or grid.GetPoints() is None:
            print(f"step {s}: no points in the output", file=sys.stderr)
            return 1
        types = vtk_to_numpy(grid.GetCellTypesArray()) if grid.GetNumberOfCells() else np.zeros(0)
        cd, pd = grid.GetCellData(), grid.GetPointData()
        steps.append(
            {
                "step": s,
                "time": reader.GetTimeValue(),
                "points": grid.GetNumberOfPoints(),
                "cells": grid.GetNumberOfCells(),
                "cell_types": sorted({int(t) for t in types}),
                "all_tetra": bool(np.all(types == vtk.VTK_TETRA)),
                "cell_arrays": sorted(cd.GetArrayName(i) for i in range(cd.GetNumberOfArrays())),
                "point_arrays": sorted(pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())),
                "gamma_s": bits(cd.GetArray("gamma_s")),
                "mass": bits(pd.GetArray("mass")),
                "point_bits": bits(grid.GetPoints().GetData()),
            }
        )
    summary = {
        "vtk_version": vtk.vtkVersion.GetVTKVersion(),
        "number_of_steps": n_steps,
        "time_values": times,
        "steps": steps,
    }
    json.dump(summary, sys.stdout)
    print()
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(sys.argv[1]))
