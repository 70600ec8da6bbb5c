"""Deep fuzz run of the readers and the builder (the cases of tests/fuzzing.py, many more of them).

The run is cut into batches; each batch is a worker process running hypothesis (random seed per
batch) that records every outcome instead of stopping at the first failure. A worker that dies
(a native abort, or the watchdog ending a hung case) is recorded as a crash with the case it
was running, and the run goes on with the next batch. The summary goes to
benchmarks/results/fuzz_deep.json: cases per target and seed format, outcomes, failures
(exception type, message, case), crashes, and the slowest case.

    nice python benchmarks/fuzz_deep.py [--reader-cases 14000] [--builder-cases 6000]
                                        [--batch 500] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DATA_DIR = Path(os.environ.get("APPROXTREE_DATA", ROOT.parent / "shared" / "data"))


def _failure(exc: BaseException, case: str) -> dict:
    """A failure record: type, message, the innermost approxtree frame, and the case."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if "approxtree" in f.filename]
    where = f"{Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else "?"
    return {"type": type(exc).__name__, "message": str(exc)[:300], "where": where, "case": case}


def worker(target: str, cases: int, seed: int, out: Path, current: Path) -> None:
    """Run one batch and write its outcomes to out (JSON); current holds the running case."""
    sys.path.insert(0, str(ROOT / "tests"))
    import fuzzing
    from hypothesis import given
    from hypothesis import seed as hypothesis_seed

    outcomes: Counter[str] = Counter()
    formats: Counter[str] = Counter()
    failures: list[dict] = []
    slowest = [0.0, ""]

    def record(case_repr: str, run) -> None:
        current.write_text(case_repr)
        t0 = time.perf_counter()
        try:
            outcomes[run()] += 1
        except Exception as exc:  # every escape is a finding
            outcomes["FAILURE"] += 1
            failures.append(_failure(exc, case_repr))
        dt = time.perf_counter() - t0
        if dt > slowest[0]:
            slowest[:] = [dt, case_repr]

    settings = fuzzing.fuzz_settings(cases, derandomize=False, seconds=60.0)
    if target == "readers":
        seeds = fuzzing.make_seeds(DATA_DIR)
        folder = Path(tempfile.mkdtemp(prefix="fuzz_deep_"))

        @hypothesis_seed(seed)
        @settings
        @given(fuzzing.reader_case(seeds))
        def run(case):
            formats[case.seed.name] += 1
            record(repr(case)[:2000], lambda: fuzzing.read_case(folder, case))

    else:
        fuzzing.warm_up_builder()

        @hypothesis_seed(seed)
        @settings
        @given(fuzzing.builder_case())
        def run(case):
            formats[f"{case['heights'].shape[0]}x{case['heights'].shape[1]}"] += 1
            shown = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in case.items()}
            record(repr(shown)[:2000], lambda: fuzzing.build_case(case))

    run()
    out.write_text(
        json.dumps(
            {
                "outcomes": outcomes,
                "formats": formats,
                "failures": failures,
                "slowest_s": slowest[0],
                "slowest_case": slowest[1],
            }
        )
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reader-cases", type=int, default=14000)
    parser.add_argument("--builder-cases", type=int, default=6000)
    parser.add_argument("--batch", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS / "fuzz_deep.json")
    parser.add_argument("--worker", choices=["readers", "builder"], help=argparse.SUPPRESS)
    parser.add_argument("--cases", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--result", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--current", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.cases, args.seed, args.result, args.current)
        return

    t0 = time.perf_counter()
    summary: dict = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "batch": args.batch,
        "seed": args.seed,
        "targets": {},
    }
    tmp = Path(tempfile.mkdtemp(prefix="fuzz_deep_run_"))
    for target, total in (("readers", args.reader_cases), ("builder", args.builder_cases)):
        outcomes: Counter[str] = Counter()
        formats: Counter[str] = Counter()
        failures: list[dict] = []
        crashes: list[dict] = []
        slowest = (0.0, "")
        t_target = time.perf_counter()
        for b, start in enumerate(range(0, total, args.batch)):
            n = min(args.batch, total - start)
            result, current = tmp / f"{target}{b}.json", tmp / f"{target}{b}.case"
            cmd = [sys.executable, __file__, "--worker", target, "--cases", str(n),
                   "--seed", str(args.seed * 100_003 + b), "--result", str(result),
                   "--current", str(current)]  # fmt: skip
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0 or not result.exists():
                crashes.append(
                    {
                        "batch": b,
                        "returncode": proc.returncode,
                        "case": current.read_text() if current.exists() else "?",
                        "stderr": proc.stderr[-3000:],
                    }
                )
                print(f"{target} batch {b}: CRASH rc={proc.returncode}", flush=True)
                continue
            part = json.loads(result.read_text())
            outcomes.update(part["outcomes"])
            formats.update(part["formats"])
            failures += part["failures"]
            if part["slowest_s"] > slowest[0]:
                slowest = (part["slowest_s"], part["slowest_case"])
            print(f"{target} batch {b}: {dict(part['outcomes'])}", flush=True)
        # One entry per distinct (type, place) with a count and the first case.
        distinct: dict[tuple[str, str], dict] = {}
        for f in failures:
            key = (f["type"], f["where"])
            distinct.setdefault(key, {**f, "count": 0})["count"] += 1
        summary["targets"][target] = {
            "cases": outcomes.total(),
            "outcomes": dict(outcomes),
            "per_format": dict(formats),
            "failures": list(distinct.values()),
            "crashes": crashes,
            "slowest_case_s": round(slowest[0], 3),
            "slowest_case": slowest[1],
            "seconds": round(time.perf_counter() - t_target, 1),
        }
    summary["total_cases"] = sum(t["cases"] for t in summary["targets"].values())
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: v for k, v in summary.items() if k != "targets"}))
    for target, t in summary["targets"].items():
        print(target, t["cases"], t["outcomes"], "failures:", len(t["failures"]),
              "crashes:", len(t["crashes"]))  # fmt: skip


if __name__ == "__main__":
    main()
