"""``python -m depthmocap.bench``: the same as ``runtime-bench`` / ``make bench``'s speed half."""

from .cli import main

main()
