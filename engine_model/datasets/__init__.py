"""Fleet data sets on disk: hyprog parquet, the N-CMAPSS h5 layout, C-MAPSS text (read).

One module per job; this package re-exports the public names of all of them, so
``from engine_model.datasets import read_dataset, write_parquet`` is the import to use.

==============  ===============================================================================
module          what is inside
==============  ===============================================================================
``schema``      the table: column groups, canonical order, required columns, integer keys,
                sorting and normalising a table, column selection
``metadata``    the metadata JSON stored with a table (keys, version, sample rate)
``jsonable``    Python and numpy values as JSON data (every JSON hyprog writes)
``fingerprint`` what identifies data: hashes of a table's rows, of a table with its
                metadata, of a dataset's files
``provenance``  is an existing path a dataset hyprog wrote (the data sets' output kinds)
``paths``       format detection (directory / suffix / magic bytes)
``parquet``     hyprog parquet, partitioned by unit (the native format)
``ncmapss_h5``  the N-CMAPSS h5 layout of the published files
``dispatch``    :func:`read_dataset` / :func:`write_dataset` / :func:`read_metadata` /
                :func:`read_columns` for either format
``dataset``     :class:`Dataset`: a table, its metadata and its split as one object
``summary``     :func:`summarize` (``hyprog data info``)
``cmapss``      the C-MAPSS (2008) text files (train / test / RUL) read into the same table
==============  ===============================================================================

Each module's docstring describes its format. Reading data never imports CasADi or torch.
"""

from .cmapss import (
    CMAPSS_COLUMNS,
    CMAPSS_SENSORS,
    CMAPSS_SETTINGS,
    CMAPSS_SOURCE,
    read_cmapss,
    read_cmapss_text,
    read_rul_file,
)
from .dataset import Dataset, load_sample
from .dispatch import read_columns, read_dataset, read_metadata, write_dataset
from .metadata import META_KEY, SAMPLE_RATE_KEY, hyprog_version
from .ncmapss_h5 import (
    DEFAULT_H5_RATE_HZ,
    H5_CHUNK_ROWS,
    H5_GROUPS,
    H5_INT_GROUPS,
    H5_REQUIRED,
    NCMAPSS_SOURCE,
    read_ncmapss_h5,
    write_ncmapss_h5,
)
from .parquet import (
    PARQUET_COMPRESSION,
    PARQUET_PART,
    parquet_unit_writer,
    read_parquet,
    write_parquet,
    write_unit_part,
    written_units,
)
from .paths import H5_SUFFIXES, output_format
from .provenance import check_dataset_output, written_by_hyprog
from .schema import (
    BOOKKEEPING,
    INT_KEYS,
    INT_OPTIONAL,
    REQUIRED_COLUMNS,
    SOURCE_ROW,
    SPLITS,
    canonical_columns,
    column_groups,
)
from .summary import summarize

__all__ = [
    "Dataset", "load_sample",
    "BOOKKEEPING", "REQUIRED_COLUMNS", "INT_KEYS", "INT_OPTIONAL", "SPLITS", "META_KEY",
    "SAMPLE_RATE_KEY", "NCMAPSS_SOURCE", "DEFAULT_H5_RATE_HZ", "PARQUET_PART",
    "PARQUET_COMPRESSION", "H5_SUFFIXES", "H5_GROUPS", "H5_REQUIRED", "H5_INT_GROUPS",
    "H5_CHUNK_ROWS",
    "write_parquet", "read_parquet", "read_metadata", "read_columns", "write_ncmapss_h5",
    "read_ncmapss_h5", "read_dataset", "write_dataset", "summarize", "canonical_columns",
    "column_groups", "written_units", "write_unit_part", "parquet_unit_writer",
    "hyprog_version", "SOURCE_ROW", "check_dataset_output", "written_by_hyprog",
    "CMAPSS_COLUMNS", "CMAPSS_SENSORS", "CMAPSS_SETTINGS", "CMAPSS_SOURCE", "read_cmapss",
    "read_cmapss_text", "read_rul_file", "output_format",
]
