"""YAML for files a person writes (scenarios, container catalogues): a key given twice is an
error, not silently the last value, and every error names the file, line and column."""

from __future__ import annotations

from typing import Any

import yaml

_MERGE_TAG = "tag:yaml.org,2002:merge"


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (a plain load keeps
    the last value given, silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict[Any, yaml.Mark] = {}
        for key_node, _ in node.value:
            if key_node.tag == _MERGE_TAG:  # `<<: *base` may repeat the base's keys
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                first = seen.setdefault(key, key_node.start_mark)
            except TypeError:  # an unhashable key: the base class says so
                break
            if first is not key_node.start_mark:
                raise yaml.constructor.ConstructorError(
                    None, None, f"the key '{key}' is given twice (first on line "
                    f"{first.line + 1}); expected each key once", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def load_yaml(text: str, label: str, error: type[Exception] = ValueError) -> Any:
    """`text` parsed as YAML, or `error` naming `label` (e.g. "scenario file 'x.yaml'"), the
    line and column, and the problem; a duplicate key is an error."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader: no arbitrary objects
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark
        where = f", line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        context = f" {e.context}," if e.context else ""
        raise error(f"{label}{where}: not valid YAML:{context} {e.problem}") from e
    except yaml.YAMLError as e:
        raise error(f"{label}: not valid YAML: {e}") from e
