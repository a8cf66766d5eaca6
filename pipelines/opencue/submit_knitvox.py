#!/usr/bin/env python3
"""Submit a knitvox job manifest to OpenCue: one layer per stage, each
depending on the layer before (pyoutline).

    submit_knitvox.py JOB.toml [--knitvox PATH] [--show SHOW] [--shot SHOT] [--dry-run]

The stages come from `knitvox run JOB.toml --plan --json` (the same plan
`knitvox run --submit slurm` submits); each frame runs
`knitvox run JOB.toml --stage NAME --json` on a host, so the paths in the
manifest and the knitvox binary must be visible from the render hosts.

Exit classes (schemas/job.md, "Farm submission"): OpenCue retries a failed
frame up to the layer's retry count whatever its exit code (right for exit
75, transient); for 65/66/69/74 the frame log names the file and the fix.

Not run by knitvox's tests (no Cuebot there); needs OpenCue's pyoutline and
pycue, configured for your Cuebot.
"""
import argparse
import json
import os
import subprocess
import sys


def unsafe(value):
    """A control byte (below 0x20, or 0x7f) would start a new line of a
    submission file or a shell command; knitvox refuses such names when it
    builds the plan, and this submitter refuses them again."""
    return any(ord(c) < 0x20 or ord(c) == 0x7f for c in value)


def refuse(what, value, code):
    shown = repr(value)
    if len(shown) > 120:
        shown = shown[:120] + "..."
    sys.stderr.write(f"error: {what} {shown} holds a control character\n")
    sys.exit(code)


def check_plan(node, where="plan"):
    """Every string of the plan, keys included (exit 65, bad input)."""
    if isinstance(node, str):
        if unsafe(node):
            refuse(f"the {where} value", node, 65)
    elif isinstance(node, dict):
        for k, v in node.items():
            check_plan(k, where)
            check_plan(v, f"{where}.{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            check_plan(v, f"{where}[{i}]")


def plan(knitvox, job):
    out = subprocess.run([knitvox, "run", job, "--plan", "--json", "--knitvox", knitvox],
                         check=True, capture_output=True, text=True)
    p = json.loads(out.stdout)
    check_plan(p)
    return p


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("job")
    ap.add_argument("--knitvox", default="knitvox", help="knitvox on the render hosts")
    ap.add_argument("--show", default=os.environ.get("SHOW", "testing"))
    ap.add_argument("--shot", default=os.environ.get("SHOT", "knitvox"))
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args()
    for flag in ("show", "shot", "knitvox"):
        if unsafe(getattr(a, flag)):
            refuse(f"--{flag}", getattr(a, flag), 2)

    p = plan(a.knitvox, os.path.abspath(a.job))
    if a.dry_run:
        for stage in p["stages"]:
            after = f" (after {', '.join(stage['after'])})" if stage["after"] else ""
            print(f"{stage['name']}{after}: frames 0-{stage['tasks'] - 1}: {' '.join(stage['argv'])}")
        return 0

    from outline import Outline, cuerun  # OpenCue's pyoutline
    from outline.modules.shell import Shell

    ol = Outline(f"knitvox_{p['name']}", show=a.show, shot=a.shot)
    layers = {}
    for stage in p["stages"]:
        argv = stage["argv"]
        if stage["tasks"] > 1:
            argv = argv + ["--task", "#IFRAME#"]
        layer = Shell(stage["name"], command=argv, range=f"0-{stage['tasks'] - 1}")
        for up in stage["after"]:
            layer.depend_on(layers[up])
        layers[stage["name"]] = layer
        ol.add_layer(layer)
    jobs = cuerun.launch(ol, use_pycuerun=False)
    for j in jobs:
        print(f"opencue job {j.name()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
