"""Perturbations of an attack (paper figure 5) have the stated statistics."""

import numpy as np
import pytest

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.robustness import perturb


@pytest.mark.parametrize("strength", [0.0, 0.1, 0.3])
def test_perturbation_flips_present_frames_with_probability_s_and_adds_noise_of_std_s(strength):
    shape = (400, 6)
    present = np.ones(shape, dtype=bool)
    present[:, 5] = False  # an agent never present is never flipped
    errors = PerceptionErrors.none(*shape)
    errors.fn[::3] = True
    out = perturb(errors, present, strength, np.random.default_rng(1))
    flipped = out.fn != errors.fn
    assert not flipped[:, 5].any()
    assert flipped[:, :5].mean() == pytest.approx(strength, abs=0.02)
    assert out.dx.std() == pytest.approx(strength, abs=0.01)
    assert np.array_equal(out.dyaw, errors.dyaw)
    assert not np.shares_memory(out.fn, errors.fn)
