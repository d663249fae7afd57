"""The sections-on mask codec (common.section_masks): bit k the k-th section from the left, both ways."""

import numpy as np
import pytest

from vrsim.common.section_masks import section_mask_codes, section_masks, sections_from_masks


def test_six_sections_read_as_the_paper_writes_them():
    gates = np.array([[1, 1, 1, 1, 1, 1], [1, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 1], [0] * 6], bool)
    assert section_masks(gates) == ["0x3f", "0x1", "0x20", "0x0"]


@pytest.mark.parametrize("sections", [1, 6, 63, 64, 70])
def test_masks_read_back_to_the_gates_also_past_63_sections(sections):
    gates = np.random.default_rng(sections).random((50, sections)) < 0.5
    codes, masks = section_mask_codes(gates)
    assert len(set(masks)) == len(masks) and np.array_equal(np.array(masks)[codes], section_masks(gates))
    assert np.array_equal(sections_from_masks(section_masks(gates), sections), gates)


@pytest.mark.parametrize("mask", ["3f", "0x40", "0xzz", "-0x1", None])
def test_a_mask_that_is_not_one_of_these_sections_names_itself(mask):
    with pytest.raises(ValueError, match="is not a bitmask of 6 sections"):
        sections_from_masks(["0x3f", mask], 6)
