#!/usr/bin/env python3
"""Drop-to-first-output latency and idle overhead of `knitvox watch` (docs/performance.md).

    python3 benches/watch.py target/release/knitvox latency                        # inotify
    python3 benches/watch.py target/release/knitvox latency --no-inotify --poll 2  # polled
    python3 benches/watch.py target/release/knitvox idle                           # CPU, RSS over 60 s

latency: a daemon on a fresh ROOT (local temp folder); DROPS (default 9) times, a
4x4 rib swatch (`knitvox pattern rib1x1 --courses 4 --wales 4 --no-relax`) is
renamed into inbox/ at a random phase and the time until out/NAME/garment.vtkhdf
exists is taken (5 ms polling); prints median, min, max and the daemon's RSS.
idle: CPU time (utime + stime from /proc/PID/stat) of an idle daemon over SECS
(default 60) seconds, and its RSS.
"""
import os, random, shutil, statistics, subprocess, sys, tempfile, time

exe, mode, flags = sys.argv[1], sys.argv[2], sys.argv[3:]
root = tempfile.mkdtemp(prefix="kvwatch-")
stage = os.path.join(root, "stage")
os.makedirs(stage)
log = open(os.path.join(root, "log.jsonl"), "w")
d = subprocess.Popen([exe, "watch", root] + flags, stdout=log, stderr=subprocess.STDOUT)
time.sleep(2)
if mode == "latency":
    src = os.path.join(stage, "rib.bcc")
    subprocess.run([exe, "pattern", "rib1x1", "--courses", "4", "--wales", "4",
                    "--no-relax", "-o", src], check=True, capture_output=True)
    lat = []
    for i in range(int(os.environ.get("DROPS", "9"))):
        name = f"s{i}"
        shutil.copy(src, os.path.join(stage, name + ".bcc"))
        time.sleep(random.uniform(0.0, 2.0))  # uniform phase against the poll
        t0 = time.time()
        os.rename(os.path.join(stage, name + ".bcc"), os.path.join(root, "inbox", name + ".bcc"))
        out = os.path.join(root, "out", name, "garment.vtkhdf")
        while not os.path.exists(out):
            time.sleep(0.005)
        lat.append(time.time() - t0)
    print("latency s: median %.2f  min %.2f  max %.2f  (n=%d) %s" % (
        statistics.median(lat), min(lat), max(lat), len(lat), " ".join("%.2f" % x for x in lat)))
    st = dict(l.split(":", 1) for l in open(f"/proc/{d.pid}/status"))
    print("daemon after the drops: VmRSS %s; VmHWM %s" % (st["VmRSS"].strip(), st["VmHWM"].strip()))
else:
    tck = os.sysconf("SC_CLK_TCK")
    def ticks():
        f = open(f"/proc/{d.pid}/stat").read().rsplit(")", 1)[1].split()
        return int(f[11]) + int(f[12])
    secs = float(os.environ.get("SECS", "60"))
    a, t = ticks(), time.time()
    time.sleep(secs)
    b, t = ticks(), time.time() - t
    st = dict(l.split(":", 1) for l in open(f"/proc/{d.pid}/status"))
    print("idle CPU %.3f%% over %.0f s; VmRSS %s; VmHWM %s" % (
        100.0 * (b - a) / tck / t, t, st["VmRSS"].strip(), st["VmHWM"].strip()))
d.terminate()
d.wait(30)
shutil.rmtree(root)
