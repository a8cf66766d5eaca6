#!/usr/bin/env python3
"""Submit a knitvox job manifest to AWS Thinkbox Deadline: one Deadline job
per stage (CommandLine plugin), chained with JobDependencies.

    submit_knitvox.py JOB.toml [--knitvox PATH] [--pool P] [--group G]
                      [--priority N] [--retries N] [--dry-run]

The stages come from `knitvox run JOB.toml --plan --json` (the same plan
`knitvox run --submit slurm` submits); each Deadline task runs
`knitvox run JOB.toml --stage NAME --json` on a worker, so the paths in the
manifest and the knitvox binary must be visible from the workers.

Exit classes (schemas/job.md, "Farm submission"): Deadline cannot branch on
a task's exit code, so every failure is retried up to --retries times
(right for exit 75, transient); for 65/66/69/74 the task log names the
file and the fix, and a person requeues the job after fixing it.
Job info and plugin info files are kept under OUT/.knitvox/submit/deadline/.

Not run by knitvox's tests (no Deadline repository there); the key names are
Deadline 10's manual-submission keys.
"""
import argparse
import json
import os
import re
import shlex
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


def write(path, lines):
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("job")
    ap.add_argument("--knitvox", default="knitvox", help="knitvox on the workers")
    ap.add_argument("--pool", default="none")
    ap.add_argument("--group", default="none")
    ap.add_argument("--priority", type=int, default=50)
    ap.add_argument("--retries", type=int, default=3)
    ap.add_argument("--deadlinecommand", default="deadlinecommand")
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args()
    for flag in ("pool", "group", "deadlinecommand", "knitvox"):
        if unsafe(getattr(a, flag)):
            refuse(f"--{flag}", getattr(a, flag), 2)

    p = plan(a.knitvox, os.path.abspath(a.job))
    folder = os.path.join(p["output"], ".knitvox", "submit", "deadline")
    os.makedirs(folder, exist_ok=True)
    ids = {}
    for stage in p["stages"]:
        name = stage["name"]
        deps = [ids[s] for s in stage["after"] if s in ids]
        job_info = [
            "Plugin=CommandLine",
            f"Name={p['name']}:{name}",
            f"BatchName=knitvox {p['name']}",
            f"Frames=0-{stage['tasks'] - 1}",
            "ChunkSize=1",
            f"Pool={a.pool}",
            f"Group={a.group}",
            f"Priority={a.priority}",
            "OverrideTaskFailureDetection=True",
            f"FailureDetectionTaskErrors={a.retries + 1}",
        ]
        if deps:
            job_info.append("JobDependencies=" + ",".join(deps))
        argv = stage["argv"]
        if stage["tasks"] > 1:
            argv = argv + ["--task", "<STARTFRAME>"]
        plugin_info = [
            f"Executable={argv[0]}",
            "Arguments=" + " ".join(shlex.quote(x) for x in argv[1:]),
            f"StartupDirectory={os.path.dirname(p['job'])}",
            "Shell=default",
            "ShellExecute=False",
            "SingleFramesOnly=True",
        ]
        ji = os.path.join(folder, f"{name}.job_info.job")
        pi = os.path.join(folder, f"{name}.plugin_info.job")
        write(ji, job_info)
        write(pi, plugin_info)
        if a.dry_run:
            ids[name] = f"<{name}>"
            print(f"{name}: {a.deadlinecommand} {ji} {pi}")
            continue
        out = subprocess.run([a.deadlinecommand, ji, pi], capture_output=True, text=True)
        m = re.search(r"JobID=(\S+)", out.stdout)
        if out.returncode != 0 or not m:
            sys.stderr.write(f"deadline refused stage {name}: {out.stdout}{out.stderr}\n")
            return 75
        ids[name] = m.group(1)
        print(f"{name}: deadline job {ids[name]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
