"""Sample data packaged with hyprog, found through :mod:`importlib.resources` (never by a
path relative to the source tree, so an installed wheel finds it as a checkout does).

============================================  ================================================
resource                                      what it is
============================================  ================================================
``tiny/``                                     a four-unit fleet made by the simulator's
                                              ``tiny`` preset (hyprog parquet; units 1-3
                                              development, 4 test): the default data of
                                              ``hyprog pipeline`` and of the tests
``cmapss-fd002-operating-points.csv``         C-MAPSS FD002's six operating-point means, the
                                              default reference table of
                                              ``hyprog model reference``
============================================  ================================================

    from engine_model.datasets import load_sample
    fleet = load_sample()                 # a Dataset: table, metadata, split
    path = sample_path("tiny")            # where it lies, for the command line
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

TINY_FLEET = "tiny"
REFERENCE_CSV = "cmapss-fd002-operating-points.csv"


def sample_path(name: str) -> Path:
    """The file-system path of the packaged resource ``name`` (e.g. ``"tiny"``).

    hyprog is installed as plain files (pip unpacks wheels; an editable install points at the
    checkout), so the resource is a real path that every reader can open. A missing resource
    is a ``FileNotFoundError`` naming it."""
    resource = files(__name__) / name
    path = Path(str(resource))
    if not path.exists():
        raise FileNotFoundError(f"hyprog sample data {name!r} is not installed (looked in "
                                f"{path.parent})")
    return path


__all__ = ["REFERENCE_CSV", "TINY_FLEET", "sample_path"]
