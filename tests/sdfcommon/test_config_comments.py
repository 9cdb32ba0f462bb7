"""sdfcommon.tooling.config_comments: the YAML comments that document each setting, read by key and
printed beside the composed settings (the commands' --help)."""
from __future__ import annotations

from sdfcommon.tooling.config_comments import COMMENT_COLUMN, commented_yaml, yaml_comments

YAML = """\
# A file's header: about the file, no setting's.
# It goes on for lines.
_target_: some.Class
plain: 1
seed: 0                  # seeds everything
long: '#not a comment'   # the value holds a hash
views: [0, 6]            # NMR views 0..23
calibrate: true          # calibrate the checkpoints
                         # (the second line of the same comment)
next: false
# GPUs per node: the comment above a setting
devices: 2
nested:                  # a group of settings
  inner: 3               # paper: 3
  list:
    - 1                  # inside a list: nobody's
  deeper:
    leaf: x
"""


def test_each_setting_gets_its_own_comment_by_key():
    found = yaml_comments(YAML)
    assert found == {
        "seed": ["seeds everything"],
        "long": ["the value holds a hash"],
        "views": ["NMR views 0..23"],
        "calibrate": ["calibrate the checkpoints", "(the second line of the same comment)"],
        "devices": ["GPUs per node: the comment above a setting"],
        "nested": ["a group of settings"],
        "nested.inner": ["paper: 3"],
    }
    # A group file's keys go under its package.
    assert yaml_comments(YAML, "data")["data.nested.inner"] == ["paper: 3"]
    assert yaml_comments("just: [unclosed") == {} and yaml_comments("- a list\n") == {}


def test_the_composed_settings_print_with_their_comments():
    settings = {"seed": 0, "views": [0, 6], "out": "${paths.output_dir}/x", "ckpt": "???",
                "nested": {"inner": 3, "empty": {}}, "note": "two\nlines"}
    text = commented_yaml(settings, {"seed": ["seeds everything"], "nested.inner": ["paper: 3", "(more)"]})
    assert text.splitlines() == [
        "seed: 0".ljust(COMMENT_COLUMN) + "# seeds everything",
        "views: [0, 6]",
        "out: ${paths.output_dir}/x",
        "ckpt: ???",
        "nested:",
        "  inner: 3".ljust(COMMENT_COLUMN) + "# paper: 3",
        " " * COMMENT_COLUMN + "# (more)",
        "  empty: {}",
        'note: "two\\nlines"',
    ]
