"""Every shipped example's ``--summary``, byte for byte, against a recorded set.

A change that must not change behaviour (a move of modules, a refactor of the run loop) runs
this before and after::

    python benchmarks/same_summaries.py --write /tmp/before     # at the old commit
    python benchmarks/same_summaries.py --compare /tmp/before   # at the new one

Each example runs as ``python -m pcmm.cli run EXAMPLE --summary`` in a child process (the
sources found first on ``PYTHONPATH``, or the installed pcmm). What may differ between two
runs of the same code is taken out: timings (``wall_s``, ``record_s``), the scene's absolute path, and
the evaluations' "why not" text where the compiled extension is absent. Everything else must be
identical: every event, every number's repr, every key and its order. Prints the first differing
line per example and exits 1 on any difference.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TIMINGS = ("wall_s", "record_s")


def examples() -> list[Path]:
    return sorted((ROOT / "examples").glob("*.toml"))  # examples/studies/ holds study plans, not scenes


def normalised(summary: dict) -> dict:
    summary["scene"] = Path(summary["scene"]).name
    stats = summary.get("stats", {})
    for key in TIMINGS:
        stats.pop(key, None)
    return summary


def summary_of(example: Path, work: Path) -> str:
    out = work / f"{example.stem}.json"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (os.environ.get("PYTHONPATH"), str(ROOT)) if p))
    proc = subprocess.run([sys.executable, "-m", "pcmm.cli", "run", str(example), "--summary", str(out), "--quiet",
                           "--force"], cwd=work, env=env, capture_output=True, text=True)
    if not out.is_file():
        return f"(no summary: exit {proc.returncode})\n{proc.stderr}"
    return json.dumps(normalised(json.loads(out.read_text())), indent=1) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", type=Path, metavar="DIR", help="record every example's summary in DIR")
    mode.add_argument("--compare", type=Path, metavar="DIR", help="compare every example's summary with DIR's")
    args = ap.parse_args(argv)
    differ = 0
    with tempfile.TemporaryDirectory() as tmp:
        for ex in examples():
            name = ex.relative_to(ROOT / "examples").with_suffix(".json").as_posix().replace("/", "__")
            text = summary_of(ex, Path(tmp))
            if args.write:
                args.write.mkdir(parents=True, exist_ok=True)
                (args.write / name).write_text(text)
                print(f"{ex.relative_to(ROOT)}: recorded")
                continue
            ref = (args.compare / name)
            if not ref.is_file():
                print(f"{ex.relative_to(ROOT)}: no recorded summary in {args.compare}")
                differ += 1
                continue
            old, new = ref.read_text().splitlines(), text.splitlines()
            if old == new:
                print(f"{ex.relative_to(ROOT)}: identical ({len(new)} lines)")
                continue
            differ += 1
            line = next((i for i, (a, b) in enumerate(zip(old, new)) if a != b), min(len(old), len(new)))
            print(f"{ex.relative_to(ROOT)}: DIFFERS at line {line + 1}:\n  before: "
                  f"{old[line] if line < len(old) else '(end)'}\n  now:    {new[line] if line < len(new) else '(end)'}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
