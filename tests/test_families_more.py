"""The second half of tests/test_families.py's cases (see its MORE): physics outside the
catalog modelled by its family, in its own file so that the two halves run on two
workers."""

from __future__ import annotations

import pytest

from test_families import MORE, check_modelled


@pytest.mark.parametrize("mechanism", MORE)
def test_a_mechanism_outside_the_catalog_is_modelled_by_its_family(mechanism, tmp_path):
    check_modelled(mechanism, tmp_path)
