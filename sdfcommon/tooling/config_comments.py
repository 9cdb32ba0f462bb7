"""The YAML comments of the configs, for the commands' ``--help``: hydra's own help prints the
composed config without them, and they are what documents each setting (its meaning, its range,
whether the value is the paper's). ``yaml_comments`` reads one file's comments by dotted key;
``commented_yaml`` prints a composed config with each setting's comment beside it."""
from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, Optional

import yaml

# Comments start at this column where the setting leaves room (the configs' own layout).
COMMENT_COLUMN = 33


def yaml_comments(text: str, package: str = "") -> dict[str, list[str]]:
    """The comments of a YAML file's settings: dotted key -> comment lines (without ``#``).

    A setting's comment is the block of comment lines right above it at its own indentation, then
    the one at the end of its line (after its value, or after the colon of a nested mapping) and
    the comment-only lines right below that are indented deeper than the setting (its
    continuation). The comments at the top of a file (its header) and inside lists belong to no
    setting.

    Args:
        text: the file's YAML.
        package: where hydra puts the file's keys (``"data"`` for ``data/procedural.yaml``; ``""``
            for the primary config and ``# @package _global_`` files).
    Returns:
        the comments, by key with the package in front; {} for text that is not a YAML mapping.
    """
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    found: dict[str, list[str]] = {}
    if isinstance(root, yaml.MappingNode):
        lines = text.splitlines()
        header = next((i for i, line in enumerate(lines) if line.strip() and not _is_comment(line)), len(lines))
        _collect(root, package, lines, header, found)
    return found


def _is_comment(line: str) -> bool:
    return line.lstrip().startswith("#")


def _collect(node: yaml.MappingNode, prefix: str, lines: list[str], header: int,
             found: dict[str, list[str]]) -> None:
    for key_node, value_node in node.value:
        if not isinstance(key_node, yaml.ScalarNode):
            continue
        key = f"{prefix}.{key_node.value}" if prefix else str(key_node.value)
        column = key_node.start_mark.column
        above = key_node.start_mark.line
        while above > header and _is_comment(lines[above - 1]) and lines[above - 1].index("#") == column:
            above -= 1
        comment = [line.strip()[1:].strip() for line in lines[above:key_node.start_mark.line]]
        block = isinstance(value_node, (yaml.MappingNode, yaml.SequenceNode)) and not value_node.flow_style
        end = key_node.end_mark if block else value_node.end_mark
        rest = lines[end.line][end.column:].lstrip() if end.line < len(lines) else ""
        if block and rest.startswith(":"):
            rest = rest[1:].lstrip()
        if rest.startswith("#"):
            comment.append(rest[1:].strip())
            # Continuation lines sit deeper than the setting (and than a nested mapping's keys).
            deeper_than = max(column, value_node.start_mark.column if block else 0)
            below = end.line + 1
            while below < len(lines) and _is_comment(lines[below]) and lines[below].index("#") > deeper_than:
                comment.append(lines[below].strip()[1:].strip())
                below += 1
        if comment:
            found[key] = comment
        if isinstance(value_node, yaml.MappingNode):
            _collect(value_node, key, lines, header, found)


def commented_yaml(config: Mapping[str, Any], comments: Mapping[str, list[str]]) -> str:
    """``config`` as block YAML (lists of plain values inline), each setting followed by its
    comment from ``comments`` (dotted key -> lines, as ``yaml_comments`` gives them)."""
    return "\n".join(_lines(config, comments, "", 0)) + "\n"


def _lines(node: Mapping[str, Any], comments: Mapping[str, list[str]], prefix: str, indent: int) -> list[str]:
    out = []
    for key, value in node.items():
        full = f"{prefix}.{key}" if prefix else str(key)
        nested = isinstance(value, Mapping) and len(value) > 0
        code = f"{' ' * indent}{key}:" if nested else f"{' ' * indent}{key}: {_inline(value)}"
        out += _with_comment(code, comments.get(full))
        if nested:
            out += _lines(value, comments, full, indent + 2)
    return out


def _with_comment(code: str, comment: Optional[list[str]]) -> list[str]:
    if not comment:
        return [code]
    column = max(COMMENT_COLUMN, len(code) + 2)
    return [f"{code.ljust(column)}# {comment[0]}".rstrip(), *(f"{'':{column}}# {c}".rstrip() for c in comment[1:])]


def _inline(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=2**31, sort_keys=False)
    text = text[:-len("\n...\n")] if text.endswith("\n...\n") else text.rstrip("\n")
    return json.dumps(value) if "\n" in text else text


__all__ = ["yaml_comments", "commented_yaml", "COMMENT_COLUMN"]
