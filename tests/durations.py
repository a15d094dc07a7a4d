"""Sum a pytest ``--durations=0`` log per test file into tests/durations.json (the order conftest hands files out).

Run: ``python tests/durations.py LOG`` after ``./test.sh --durations=0 > LOG``.
"""

from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from pathlib import Path

LINE = re.compile(r"^\s*([0-9.]+)s\s+(?:call|setup|teardown)\s+tests/([^:]+\.py)::")


def main(log: str) -> int:
    total: dict[str, float] = defaultdict(float)
    for line in Path(log).read_text(errors="replace").splitlines():
        m = LINE.match(line)
        if m:
            total[m.group(2)] += float(m.group(1))
    out = Path(__file__).with_name("durations.json")
    out.write_text(json.dumps({k: round(v, 1) for k, v in sorted(total.items(), key=lambda kv: -kv[1])},
                              indent=1) + "\n")
    print(f"{len(total)} files, {sum(total.values()):.0f} s in all -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
