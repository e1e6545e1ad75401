"""Write a Truth record to a file the user named (.npz, .csv or .parquet)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.records import Truth


def write_truth(truth: Truth, path: str | Path) -> Path:
    """Write ``truth`` as flat columns; the format follows the suffix.

    Written to a temporary name and renamed, so an existing file is never left
    half-written.
    """
    path = Path(path)
    cols = truth.as_columns()
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".csv", ".parquet"):
        raise ValueError(f"{path}: unsupported truth format {suffix!r}; expected .npz, .csv or .parquet")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    if suffix == ".npz":
        with tmp.open("wb") as fh:
            np.savez_compressed(fh, frame_origin=truth.frame_origin, **cols)
    elif suffix == ".csv":
        names = list(cols)
        np.savetxt(tmp, np.column_stack([cols[n] for n in names]), delimiter=",", header=",".join(names),
                   comments="", fmt="%.10g")
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.table(cols).replace_schema_metadata(
            {"frame_origin_lat_lon_h": ",".join(map(repr, truth.frame_origin.tolist()))})
        pq.write_table(table, tmp)
    tmp.replace(path)
    return path
