"""Configuration: strict loading of frozen dataclasses from TOML (one-line errors naming the dotted key), the files
a user names, and the resource limits that keep a run in memory and time."""
from .files import find_file, read_toml_file, shipped_dir, shipped_names
from .strict import (ConfigError, field, from_dict, non_negative, one_line, parse_sets, positive, show_path,
                     to_dict, type_name)

__all__ = ["ConfigError", "field", "find_file", "from_dict", "non_negative", "one_line", "parse_sets", "positive",
           "read_toml_file", "shipped_dir", "shipped_names", "show_path", "to_dict", "type_name"]
