"""`make bench`: run every benchmark module in this folder (or those named), each writing bench/<name>.json/.md.

python -m bench                # all
python -m bench loop excitation
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    available = sorted(p.stem for p in HERE.glob("*.py") if not p.stem.startswith("_"))
    chosen = argv or available
    unknown = [n for n in chosen if n not in available]
    if unknown:
        print(f"unknown benchmark(s) {unknown}; valid choices: {', '.join(available)}", file=sys.stderr)
        return 2
    for name in chosen:
        start = time.perf_counter()
        print(f"== bench {name}", flush=True)
        importlib.import_module(f"bench.{name}").main()
        print(f"== bench {name} done in {time.perf_counter() - start:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
