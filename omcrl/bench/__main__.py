"""``python -m omcrl.bench <name> [--out FILE] [--quick]``: dispatch to ``omcrl.bench.<name>.main(argv)``."""

from __future__ import annotations

import importlib
import pkgutil
import sys
from collections.abc import Sequence
from pathlib import Path

import omcrl.bench as _pkg


def available() -> list[str]:
    """The benchmark modules of this package (``env``, ``pretrain``, ``rl``, ...)."""
    return sorted(m.name for m in pkgutil.iter_modules([str(Path(_pkg.__file__).parent)]) if not m.name.startswith("_"))


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    names = available()
    if not args or args[0] in ("-h", "--help"):
        print(__doc__)
        print(f"benchmarks: {', '.join(names)}")
        return 0 if args else 2
    name, rest = args[0], args[1:]
    if name not in names:
        print(f"error: benchmark {name!r} does not exist; available: {', '.join(names)}", file=sys.stderr)
        return 2
    module = importlib.import_module(f"omcrl.bench.{name}")
    rc = module.main(rest)
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
