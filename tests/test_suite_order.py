"""tests/conftest.py's start order names files that exist: a renamed file would silently
drop back among the rest and could become the run's tail again."""

from pathlib import Path

import conftest


def test_every_longest_first_file_exists():
    here = Path(__file__).resolve().parent
    missing = [name for name in conftest.LONGEST_FIRST if not (here / name).is_file()]
    assert not missing, f"renamed or removed: update LONGEST_FIRST in conftest.py: {missing}"
