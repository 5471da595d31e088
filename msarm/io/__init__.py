"""Logs and configs: the Parquet run-log format (and its ground-truth sidecar), YAML configs."""

from msarm.io.config import config_to_dict, dump_config, load_config, write_config
from msarm.io.logs import (
    SCHEMA_VERSION,
    STANDARD_TRUTH_UNITS,
    STANDARD_UNITS,
    LogMetadata,
    RunLog,
    TruthSidecar,
    read_log,
    read_sidecar,
    sidecar_path,
    write_log,
    write_sidecar,
)

__all__ = [
    "SCHEMA_VERSION",
    "STANDARD_TRUTH_UNITS",
    "STANDARD_UNITS",
    "LogMetadata",
    "RunLog",
    "TruthSidecar",
    "config_to_dict",
    "dump_config",
    "load_config",
    "read_log",
    "read_sidecar",
    "sidecar_path",
    "write_config",
    "write_log",
    "write_sidecar",
]
