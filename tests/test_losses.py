"""PPO and TPO's pure functions against numbers worked out by hand."""

import jax.numpy as jnp
import numpy as np
import pytest

from tpo.algo.lagrangian import (
    admissible,
    ancestral_advantages,
    below_best,
    lagrangian_advantages,
    violations,
)
from tpo.algo.losses import (
    clipped_surrogate,
    discounted_cumsum,
    gae,
    normalize,
)

R = jnp.array([1.0, 2.0, 3.0])
V = jnp.array([0.5, 1.0, 1.5])
V_NEXT = jnp.array([1.0, 1.5, 2.0])


def test_gae_stops_bootstrapping_at_termination():
    # gamma = lambda = 1/2. delta = (1 + .5 - .5, 2 + .75 - 1, 3 - 1.5) = (1, 1.75, 1.5)
    # A2 = 1.5; A1 = 1.75 + .25 * 1.5 = 2.125; A0 = 1 + .25 * 2.125 = 1.53125
    term = jnp.array([0.0, 0.0, 1.0])
    adv, targets = gae(R, V, V_NEXT, term, term, 0.5, 0.5)
    assert np.allclose(adv, [1.53125, 2.125, 1.5])
    assert np.allclose(targets, [2.03125, 3.125, 3.0])


def test_gae_bootstraps_at_truncation_but_cuts_the_trace():
    # Truncated at t=1: delta_1 still bootstraps from V(final obs) = 1.5, but A_1 does not
    # reach into the next episode. delta_2 = 3 + .5 * 2 - 1.5 = 2.5.
    adv, _ = gae(R, V, V_NEXT, jnp.zeros(3), jnp.array([0.0, 1.0, 0.0]), 0.5, 0.5)
    assert np.allclose(adv, [1.0 + 0.25 * 1.75, 1.75, 2.5])


def test_discounted_cumsum():
    out = discounted_cumsum(jnp.array([1.0, 1.0, 1.0, 1.0]), 0.5, jnp.array([0, 1, 0, 0.0]))
    assert np.allclose(out, [1.5, 1.0, 1.5, 1.0])


def test_clipped_surrogate():
    # ratios (0.5, 1.5), advantages (1, -1), clip 0.2: min(0.5, 0.8) = 0.5 and
    # min(-1.5, -1.2) = -1.5; the loss is -mean = 0.5.
    loss = clipped_surrogate(jnp.log(jnp.array([0.5, 1.5])), jnp.array([1.0, -1.0]), 0.2)
    assert float(loss) == pytest.approx(0.5)


def test_normalize():
    out = normalize(jnp.array([1.0, 3.0]))
    assert np.allclose(out, [-1.0, 1.0], atol=1e-6)


def test_ancestral_advantages_and_violations():
    adv = ancestral_advantages(jnp.array([[1.0, 0.0]]), jnp.array([[2.0, 1.0]]),
                               jnp.array([[3.0, 4.0]]), jnp.array([1.0]), 0.5)
    assert np.allclose(adv, [[-1.0, -1.0]])  # terminated: no bootstrap
    # A = (0.5, -2, -0.3); edges with parents (1, 2, 0) and slack (0.5, 0, 1):
    # C = (max(0, 2 - .5), max(0, .3 - 0), max(0, -.5 - 1)) = (1.5, 0.3, 0)
    c = violations(jnp.array([0.5, -2.0, -0.3]), jnp.array([1, 2, 0]),
                   jnp.array([0.5, 0.0, 1.0]))
    assert np.allclose(c, [1.5, 0.3, 0.0])
    # Telescoping, per constraint: the zero-slack one charges -A = -(-0.3)... of its parent
    # (column 0: A = 0.5, credited as -0.5) where flagged; a flag at slack > 0 changes nothing.
    zero = jnp.array([0.0, 0.0, 1.0])
    c = violations(jnp.array([0.5, -2.0, -0.3]), jnp.array([0, 2, 0]), zero,
                   jnp.array([True, False, True]))
    assert np.allclose(c, [-0.5, 0.3, 0.0])
    assert np.allclose(violations(jnp.array([0.5, -2.0, -0.3]), jnp.array([0, 2, 0]), zero,
                                  True), [-0.5, 0.3, 0.0])
    # A dead zone of 0.4 shrinks a telescoped -A towards 0 by 0.4 (-0.5 -> -0.1; -A = 2
    # -> 1.6) and leaves a rectified one as it was (the third: max(0, 2 - 0) = 2), on
    # leading [T, E] axes too; 0.6 swallows the 0.5 whole.
    c = violations(jnp.array([0.5, -2.0, -0.3]), jnp.array([0, 1, 1]), jnp.zeros(3),
                   jnp.array([True, True, False]), 0.4)
    assert np.allclose(c, [-0.1, 1.6, 2.0])
    c = violations(jnp.full((2, 4, 3), jnp.array([0.5, -2.0, -0.3])), jnp.array([0, 1, 1]),
                   jnp.zeros(3), jnp.array([True, True, False]), jnp.array([0.4, 0.4, 0.4]))
    assert c.shape == (2, 4, 3) and np.allclose(c, [-0.1, 1.6, 2.0])
    c = violations(jnp.array([0.5, -2.0, -0.3]), jnp.array([0, 2, 0]), zero, True,
                   jnp.array([0.6, 0.0, 0.6]))
    assert np.allclose(c, [0.0, 0.3, 0.0])


def test_weights_leave_samples_out_of_the_normalisation_and_the_surrogate():
    # weights (1, 1, 0): mean 2 and std 1 of (1, 3); the third sample only shifts
    x = jnp.array([1.0, 3.0, 100.0])
    w = jnp.array([1.0, 1.0, 0.0])
    assert np.allclose(normalize(x, w), [-1.0, 1.0, 98.0])
    log_ratio = jnp.log(jnp.array([0.5, 1.5, 9.0]))
    adv = jnp.array([1.0, -1.0, 5.0])
    assert float(clipped_surrogate(log_ratio, adv, 0.2, w)) == pytest.approx(
        float(clipped_surrogate(log_ratio[:2], adv[:2], 0.2)))


def test_below_best_measures_against_the_best_allowed_action():
    # Q - V = (1, 3, 2): against the best of {0, 2} (Q - V = 2): (-1, 1, 0)
    adv = jnp.array([1.0, 3.0, 2.0])
    assert below_best(adv, jnp.array([True, False, True])).tolist() == [-1.0, 1.0, 0.0]
    assert below_best(adv + 7.0, jnp.ones(3, bool)).tolist() == [-2.0, 0.0, -1.0]


def test_admissible_actions_by_hand():
    # Two constraints, three actions. Violations max(0, -(Q - V) - slack):
    # c0 (slack 0.6): (0, 0, 1.4); c1 (slack 0): (1, 0, 0). Total (1, 0, 1.4).
    adv = jnp.array([[0.0, -0.5, -2.0], [-1.0, 0.0, 0.0]])
    slack = jnp.array([0.6, 0.0])
    assert admissible(adv, slack, jnp.array([1.0, 1.0])).tolist() == [False, True, False]
    assert admissible(adv, slack, jnp.array([1.0, 0.0])).tolist() == [True, True, False]
    assert admissible(adv, slack, jnp.array([0.0, 0.0])).tolist() == [True, True, True]
    # No action is free of violation: the least total violation is kept (totals
    # (2, 1, 2)), as the relaxed exact solver does.
    worse = jnp.array([[-1.0, -0.5, -2.0], [-1.0, -0.5, 0.0]])
    assert admissible(worse, jnp.zeros(2), jnp.ones(2)).tolist() == [False, True, False]


def test_penalized_form_is_gae_on_the_lagrangian_reward():
    # penalty (0, 1, 0), beta 2: rewards (1, 0, 3). delta = (1, -0.25, 1.5);
    # A2 = 1.5, A1 = -0.25 + .25 * 1.5 = 0.125, A0 = 1 + .25 * .125 = 1.03125.
    term = jnp.array([0.0, 0.0, 1.0])
    adv, targets = lagrangian_advantages("penalized", R, V, V_NEXT, jnp.array([0.0, 1.0, 0.0]),
                                         2.0, term, term, 0.5, 0.5)
    assert np.allclose(adv, [1.03125, 0.125, 1.5])
    assert np.allclose(targets, adv + V)


def test_immediate_form_charges_the_penalty_to_its_own_action_only():
    # GAE(r) = (1.53125, 2.125, 1.5) as above; the penalty of step 1 (beta 2 x 1) comes off
    # step 1's advantage alone: step 0's is GAE's, not the penalized form's 1.03125.
    term = jnp.array([0.0, 0.0, 1.0])
    adv, targets = lagrangian_advantages("immediate", R, V, V_NEXT, jnp.array([0.0, 1.0, 0.0]),
                                         2.0, term, term, 0.5, 0.5)
    assert np.allclose(adv, [1.53125, 0.125, 1.5])
    assert np.allclose(targets, [2.03125, 3.125, 3.0])  # raw returns


def test_traced_form_is_the_penalized_advantage_on_raw_returns():
    # GAE(r) = (1.53125, 2.125, 1.5); the penalties' GAE-weighted sum (gamma lambda = 0.25)
    # is (0.25, 1, 0), times beta 2 off: the penalized form's advantage (1.03125, 0.125, 1.5)
    # with the same critic, while the critic's targets stay the raw returns.
    term = jnp.array([0.0, 0.0, 1.0])
    penalty = jnp.array([0.0, 1.0, 0.0])
    adv, targets = lagrangian_advantages("traced", R, V, V_NEXT, penalty, 2.0, term, term,
                                         0.5, 0.5)
    assert np.allclose(adv, [1.03125, 0.125, 1.5])
    assert np.allclose(targets, [2.03125, 3.125, 3.0])
    penalized, _ = lagrangian_advantages("penalized", R, V, V_NEXT, penalty, 2.0, term, term,
                                         0.5, 0.5)
    np.testing.assert_allclose(adv, penalized)


def test_traced_penalty_with_its_own_decay():
    # trace_decay = gamma = 0.5 (the second design's lambda' = 1): the penalty of step 1
    # reaches step 0 as 0.5 x 1, times beta 2 off GAE(r) = (1.53125, 2.125, 1.5).
    term = jnp.array([0.0, 0.0, 1.0])
    adv, targets = lagrangian_advantages("traced", R, V, V_NEXT, jnp.array([0.0, 1.0, 0.0]),
                                         2.0, term, term, 0.5, 0.5, trace_decay=0.5)
    assert np.allclose(adv, [1.53125 - 1.0, 0.125, 1.5])
    assert np.allclose(targets, [2.03125, 3.125, 3.0])


def test_every_form_with_beta_0_is_gae():
    term = jnp.array([0.0, 0.0, 1.0])
    penalty = jnp.array([0.3, 1.0, 2.0])
    expected = gae(R, V, V_NEXT, term, term, 0.5, 0.5)
    for form in ("penalized", "immediate", "traced"):
        got = lagrangian_advantages(form, R, V, V_NEXT, penalty, 0.0, term, term, 0.5, 0.5)
        np.testing.assert_array_equal(got, expected)


def test_shape_guards_name_the_mismatched_array():
    with pytest.raises(ValueError, match=r"done has shape \(2,\), expected \(3,\)"):
        gae(R, V, V_NEXT, jnp.zeros(3), jnp.zeros(2), 0.5, 0.5)
    with pytest.raises(ValueError, match=r"penalty has shape \(3, 1\)"):
        lagrangian_advantages("penalized", R, V, V_NEXT, jnp.zeros((3, 1)), 1.0, jnp.zeros(3),
                              jnp.zeros(3), 0.5, 0.5)
    with pytest.raises(ValueError, match="must be \\[C\\] each"):
        violations(jnp.zeros(3), jnp.array([0, 1]), jnp.zeros(3))
