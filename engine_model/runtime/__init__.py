"""Process machinery shared by every writer and every fleet command: nothing here knows about
engines, data formats or networks.

==================  =========================================================================
module              job
==================  =========================================================================
``critical``        a section a signal waits for (two renames that must both happen)
``atomic``          writing through a temporary sibling + ``os.replace``; stale temporaries
``ownership``       the one rule for an existing output path: what may be replaced, what not
``lock``            one writer per output path (a lock file with the writer's host and pid)
``cluster``         worker processes or a Dask client for the fleet commands
``shared_model``    one engine model per process for every caller that wants the default one
==================  =========================================================================
"""

from .atomic import atomic_output, remove_stale_temporaries, remove_stale_temporaries_of
from .critical import critical_section
from .lock import output_lock
from .ownership import check_output

__all__ = ["atomic_output", "check_output", "critical_section", "output_lock",
           "remove_stale_temporaries", "remove_stale_temporaries_of"]
