"""``teamslam team launch``: one process per robot, progress, gathering of the results.

Starts ``teamslam agent`` for every robot of a team file, shows the team's progress, waits for
all of them and gathers the per-robot results into the same :class:`~teamslam.msckf.team.TeamResult`
(and so the same ``metrics.json`` and figures) as the in-process runner. Ctrl-C stops every
child cleanly; a child that dies leaves the others running to the end of their timeouts, and its
absence is reported.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from tqdm import tqdm

from teamslam.msckf.team import TeamResult, load_result, merge_results
from teamslam.runtime.team_file import TeamFile

__all__ = ["agent_command", "frames_done", "gather", "launch_team"]


def frames_done(out: Path, robot: int) -> int:
    """Frames a launched robot has filtered, from its ``progress.json`` in ``out`` (0 before
    it has written one, or while the file cannot be read)."""
    try:
        return int(json.loads((out / f"robot_{robot}" / "progress.json").read_text())["frame"]) + 1
    except (OSError, ValueError, KeyError):
        return 0


def agent_command(team_path: Path, robot: int, out: Path, *extra: str) -> list[str]:
    """The command line that runs one robot of a team file as its own process."""
    return [
        sys.executable,
        "-m",
        "teamslam",
        "agent",
        "--team",
        str(team_path),
        "--robot",
        str(robot),
        "--out",
        str(out),
        *extra,
    ]


def launch_team(
    team: TeamFile,
    team_path: Path,
    out: Path,
    progress: bool | None = None,
    poll_s: float = 0.2,
    extra_args: dict[int, list[str]] | None = None,
) -> dict:
    """Run every robot as a process; returns ``{robot: exit code}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    procs = {}
    logs = {}
    for r in team.robots:
        log = open(out / f"robot_{r.id}.log", "w")
        logs[r.id] = log
        cmd = agent_command(team_path, r.id, out, *(extra_args or {}).get(r.id, []))
        procs[r.id] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
    show = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(total=None, desc="team frames", disable=not show, leave=False)
    codes: dict[int, int] = {}
    try:
        while len(codes) < len(procs):
            for rid, p in procs.items():
                if rid not in codes and p.poll() is not None:
                    codes[rid] = p.returncode
            if show:
                bar.n = sum(frames_done(out, r.id) for r in team.robots)
                bar.refresh()
            time.sleep(poll_s)
    except KeyboardInterrupt:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
        raise
    finally:
        bar.close()
        for log in logs.values():
            log.close()
    return codes


def gather(team: TeamFile, out: Path, robots: list[int] | None = None) -> TeamResult:
    """Collect the per-robot results of a launched team into one :class:`TeamResult`."""
    robots = list(range(team.n)) if robots is None else robots
    parts = [load_result(Path(out) / f"robot_{r}") for r in robots]
    return merge_results(parts, f"team file {team.team}", team.message_loss)


def exit_summary(codes: dict[int, int]) -> str:
    """One line per robot that failed."""
    bad = {r: c for r, c in codes.items() if c != 0}
    return "; ".join(f"robot {r} exited with {c}" for r, c in sorted(bad.items()))


__all__ += ["exit_summary"]
