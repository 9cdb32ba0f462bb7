"""Tests of svr/data/procedural/categories/: one file per category, test_categories.py across them all."""
import pytest

# helpers.py checks as well as measures (checked_extents): its asserts explain themselves when they fail.
pytest.register_assert_rewrite(f"{__name__}.helpers")
