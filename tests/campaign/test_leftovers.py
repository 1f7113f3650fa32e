"""app/campaign/leftovers.py in a process of its own (it makes that process a subreaper):
what Ray leaves behind under a sweep, orphans included, is ended; nothing else is."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

DRIVER = textwrap.dedent("""
    import json, os, subprocess, sys, time
    from app.campaign.leftovers import adopt_orphans, end_leftovers, live_name

    before = subprocess.Popen(["sleep", "60"])  # not Ray's, there before: kept
    kept = adopt_orphans()
    # one of Ray's as a child; one that ignores SIGTERM; one orphaned by its parent's end
    # (re-parented here, the subreaper); and a process of another kind started after
    ray_child = subprocess.Popen(["bash", "-c", "exec -a ray::FakeAgent sleep 60"])
    stubborn = subprocess.Popen(["bash", "-c", "trap '' TERM; exec -a ray::Stubborn sleep 60"])
    parent = subprocess.Popen(["bash", "-c", "bash -c 'exec -a ray::Orphan sleep 60' & "
                               "echo $!; exit 0"], stdout=subprocess.PIPE, text=True)
    orphan = int(parent.stdout.readline())
    parent.wait()
    other = subprocess.Popen(["sleep", "60"])
    time.sleep(0.3)  # the titles set, the orphan re-parented
    adopted = int(open(f"/proc/{orphan}/stat").read().rsplit(")", 1)[1].split()[1])
    t0 = time.monotonic()
    ended = end_leftovers(kept, grace_s=0.5)
    took = time.monotonic() - t0
    alive = {name: live_name(p.pid if hasattr(p, "pid") else p) is not None
             for name, p in (("before", before), ("ray_child", ray_child),
                             ("stubborn", stubborn), ("orphan", orphan), ("other", other))}
    for p in (before, other):
        p.kill(); p.wait()
    print(json.dumps({"ended": sorted(ended), "expected": sorted([ray_child.pid,
                      stubborn.pid, orphan]), "alive": alive, "adopted_by_me":
                      adopted == os.getpid(), "took_s": took}))
""")


def test_ray_s_leftovers_orphans_included_are_ended_and_nothing_else():
    proc = subprocess.run([sys.executable, "-c", DRIVER], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["adopted_by_me"]  # the orphan came here, not to init
    assert got["ended"] == got["expected"]
    assert got["alive"] == {"before": True, "ray_child": False, "stubborn": False,
                            "orphan": False, "other": True}
    assert got["took_s"] < 5.0  # SIGKILL after the grace for the one that ignores SIGTERM
