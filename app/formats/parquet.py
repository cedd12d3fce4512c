"""Parquet files of tables, when pyarrow is importable (it is optional: the CSV files say the
same)."""

from __future__ import annotations

import os

from radiosity.formats.files import temp_path


def write_parquet(path: str, table: dict) -> bool:
    """One table (dict column name -> (rows,) array) as Parquet if pyarrow is importable;
    returns whether it was written. Written whole, then renamed."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    tmp = temp_path(path)
    pq.write_table(pa.table({k: v for k, v in table.items()}), tmp)
    os.replace(tmp, path)
    return True
