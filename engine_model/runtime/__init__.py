"""Process machinery shared by every writer and every fleet command: nothing here knows about
engines, data formats or networks.

==================  =========================================================================
module              job
==================  =========================================================================
``critical``        a section a signal waits for (two renames that must both happen)
``names``           the names of hyprog's hidden entries: temporaries, backups, locks
``atomic``          writing through a temporary sibling + ``os.replace``; stale temporaries
``ownership``       the one rule of every writer: what an output may be, what may be replaced
``lock``            one writer per output path (a lock file with the writer's host and pid)
``cluster``         the one executor of the fleet commands: serial, processes or Dask
``shared_model``    one engine model per process for every caller that wants the default one
==================  =========================================================================
"""

from .atomic import (
    atomic_output,
    atomic_outputs,
    remove_stale_temporaries,
    remove_stale_temporaries_of,
)
from .critical import critical_section
from .lock import output_lock
from .ownership import OWNED_FILE, OutputKind, check_output

__all__ = ["OWNED_FILE", "OutputKind", "atomic_output", "atomic_outputs", "check_output",
           "critical_section", "output_lock", "remove_stale_temporaries",
           "remove_stale_temporaries_of"]
