"""The end of a run: every phase's final policy is kept, and the answer is selected
among them by the tie rule (tpo.algo.selection)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import serialization

from tpo.algo import TPO, selection
from tpo.algo.config import TPOConfig
from tpo.algo.evaluate import episode_returns
from tpo.algo.persist import restore_state
from tpo.algo.selection import SELECT_EPISODES, select, select_member, select_phase
from tpo.algo.train import Trainer
from tpo.envs import OBJECTIVES, load_map
from tpo.envs.grid import GridNav
from tpo.graph import ObjectiveGraph
from tpo.tabular.judge import RANGE_SHARE

# Candidates of M>A>G, phases (monitor, avoid, goal); the last is the leaf's own.
# Order: the leaf (goal, phase 2) first, then monitor, then avoid.
ORDER = [2, 0, 1]


def pick(returns, penalty, penalty_tolerance=10.0):
    return int(select_phase(jnp.array(returns, jnp.float32), jnp.array(penalty, jnp.float32), ORDER,
                            penalty_tolerance))


def test_an_indifferent_leaf_takes_the_root_s_policy():
    # Every candidate misses the goal alike (-86.6): the monitor decides.
    returns = [[77.0, -9.0, -86.6], [0.0, 0.0, -86.6], [3.0, -20.0, -86.6]]
    assert pick(returns, [3.0, 0.0, 0.0]) == 0
    # Over the penalty tolerance, the root's policy is not admissible: of the rest
    # the monitor's best (3 against 0) answers.
    assert pick(returns, [12.0, 0.0, 0.0]) == 2


def test_the_leaf_s_objective_comes_first_and_ties_keep_the_leaf_s_policy():
    returns = [[77.0, -9.0, -86.6], [0.0, 0.0, -86.6], [0.0, 0.0, -24.5]]
    assert pick(returns, [0.0, 0.0, 0.0]) == 2  # the goal reached: the leaf's own
    # Within half a step on the goal, the monitor decides.
    assert pick([[77.0, -9.0, -24.6], *returns[1:]], [0.0, 0.0, 0.0]) == 0
    # All tied on every objective: the reference (the last) answers.
    assert pick([[1.0, 1.0, -20.0]] * 3, [0.0, 0.0, 0.0]) == 2


def test_penalties_count_against_the_leaf_s_own():
    returns = [[77.0, -9.0, -86.6], [0.0, 0.0, -86.6], [0.0, 0.0, -86.6]]
    assert pick(returns, [30.0, 0.0, 25.0]) == 0  # 5 more than the leaf's: within 10
    assert pick(returns, [36.0, 0.0, 25.0]) == 2  # 11 more


def test_a_candidate_that_loses_a_zero_slack_parent_s_return_is_no_candidate():
    # M>A>G at (100, 0) on hall: the monitor phase's policy crosses the rug to the
    # meeting room (avoid -4.4) where the leaf keeps the avoid at 0; its penalty is
    # within the allowance, but the leaf holds the avoid at zero slack.
    returns = [[82.6, -4.4, -100.0], [0.0, 0.0, -100.0], [0.0, 0.0, -100.0]]
    assert pick(returns, [4.4, 0.0, 0.0]) == 0  # the allowance alone admits it
    held = jnp.array([False, True, False])
    assert int(select_phase(jnp.array(returns), jnp.array([4.4, 0.0, 0.0]), ORDER, 10.0,
                            held)) == 2
    # Within the verdicts' tolerance of the leaf's avoid (0.5) it stays a candidate.
    returns[0][1] = -0.4
    assert int(select_phase(jnp.array(returns), jnp.array([0.4, 0.0, 0.0]), ORDER, 10.0,
                            held)) == 0


def test_a_candidate_better_on_a_higher_held_objective_may_lose_a_lower_one():
    # M>A>G at (0, 0) on home: the leaf's policy gave up 3 of the monitor root's 77 to
    # keep out of the rug (a violation of the monitor's zero slack); the monitor phase's
    # own policy, worse on the avoid below it, is lexicographically the better.
    returns = jnp.array([[77.0, -9.0, -100.0], [74.0, 0.0, -100.0], [74.0, 0.0, -100.0]])
    both = jnp.array([True, True, False])
    assert int(select_phase(returns, jnp.array([9.0, 0.0, 0.0]), ORDER, 10.0, both)) == 0
    # Tied on the monitor, the avoid decides: the leaf's own answers.
    tied = returns.at[0, 0].set(74.2)
    assert int(select_phase(tied, jnp.array([9.0, 0.0, 0.0]), ORDER, 10.0, both)) == 2


def test_a_phase_s_policy_that_the_leaf_beats_on_its_own_objective_is_no_candidate():
    # Deep Sea Treasure, treasure > time at slack 0: the treasure phase ended with the
    # 17-step treasure 22.4, the leaf with the 19-step 23.7. Faster, but not the
    # treasure's optimum: the leaf's own answers.
    returns = jnp.array([[22.4, -17.0], [23.7, -19.0]])
    assert int(select_phase(returns, jnp.zeros(2), [1, 0], 100.0)) == 1
    assert int(select_phase(returns.at[0, 0].set(23.5), jnp.zeros(2), [1, 0],
                            100.0)) == 0  # within 0.5 of the leaf's: it would answer


def test_returns_tie_within_a_scale_free_tolerance_off_the_maps():
    # The same in units of 0.01 treasure: 0.224 against 0.237 ties within 0.5 (and the
    # faster policy would answer), not within 2 % of 0.237 or 0.0025 of the spread.
    returns = jnp.array([[0.224, -17.0], [0.237, -19.0]])
    assert int(select_phase(returns, jnp.zeros(2), [1, 0], 100.0)) == 0
    absolute = RANGE_SHARE * (returns.max(0) - returns.min(0))
    assert absolute.tolist() == pytest.approx([0.0025 * 0.013, 0.0025 * 2.0])
    assert int(select_phase(returns, jnp.zeros(2), [1, 0], 100.0, absolute=absolute)) == 1
    # the member rule reads the same tolerance: member 0 answers with the faster policy
    members = jnp.stack([returns, returns[::-1]])
    picks = jnp.array([0, 0])
    assert int(select_member(members, picks, [(0, 1)], jnp.zeros(1), [1, 0])) == 0
    assert int(select_member(members, picks, [(0, 1)], jnp.zeros(1), [1, 0], absolute)) == 1


def test_a_reference_before_the_last_candidate():
    # The fan A>G, M>G: phases (avoid, monitor, goal, monitor under avoid), the leaf's
    # (2) the reference. At slack 5 the goal is out of reach alike; the roots'
    # completion keeps the avoid at 0 and reaches the study (74): it answers.
    returns = jnp.array([[0.0, 0.0, -86.6, 0.0], [-9.0, 77.0, -86.6, 77.0],
                         [0.0, 0.0, -86.6, 0.0], [0.0, 74.0, -86.6, 74.0]])
    order = [2, 0, 1]
    assert int(select_phase(returns, jnp.zeros(4), order, 10.0, reference=2)) == 3
    # Its penalty counts against the leaf's (12 over 0), not against its own: the
    # avoid's best then keeps the avoid phase's and the leaf's, tied: the leaf's.
    penalty = jnp.array([0.0, 0.0, 0.0, 12.0])
    assert int(select_phase(returns, penalty, order, 10.0, reference=2)) == 2
    assert int(select_phase(returns, penalty, order, 10.0)) == 3  # the last as the reference
    # Tied on every objective: the reference answers, though a later one ties too.
    assert int(select_phase(jnp.zeros((4, 4)), jnp.zeros(4), order, 10.0, reference=2)) == 2


def test_a_leaf_that_lost_a_zero_slack_parent_s_best_does_not_hand_it_to_the_root():
    # G>M>A at (100, 0) on the continuous home, phases (goal, monitor, avoid): the
    # monitor phase reaches the kitchen (61.7); the avoid leaf's policy lost it (0), and
    # every candidate's avoid is the start's rug (-16.3). Against the leaf's own
    # returns the goal phase's policy is no worse on the held monitor and better on the
    # root: it answered. By LAR's rule on the candidates the answer keeps the
    # monitor's best within the judge's tolerance: the monitor phase's policy.
    returns = jnp.array([[-32.4, 0.0, -16.3], [-100.0, 61.7, -16.3], [-100.0, 0.0, -16.3]])
    held, order = jnp.array([False, True, False]), [2, 0, 1]
    edges = [(0, 1), (1, 2)]  # goal -> monitor, monitor -> avoid
    allowance = jnp.array([10000.0, 0.0])  # local slacks (100, 0) over 1 - gamma
    assert int(select_phase(returns, jnp.zeros(3), order, 10.0, held)) == 0
    assert int(select_phase(returns, jnp.zeros(3), order, 10.0, held, edges=edges,
                            allowance=allowance)) == 1
    # A leaf within the tolerance of the monitor's best (2 %) keeps its own answer.
    kept = returns.at[2, 1].set(60.6)
    assert int(select_phase(kept, jnp.zeros(3), order, 10.0, held, edges=edges,
                            allowance=allowance)) == 2
    # No admissible candidate keeps the edges (the monitor's best is a policy whose
    # penalty excludes it): the rule stands aside, and the answer is as without it.
    assert int(select_phase(returns, jnp.array([0.0, 30.0, 0.0]), order, 10.0, held,
                            edges=edges, allowance=allowance)) == 0
    with pytest.raises(ValueError, match="edges need their allowance"):
        select_phase(returns, jnp.zeros(3), order, 10.0, held, edges=edges)


def test_a_leaf_that_lost_a_parent_s_best_does_not_bar_that_objective_s_phase():
    # M>A>G at (0, 0) on the continuous held2: the avoid phase keeps the monitor's
    # closet (79.2) through the door's one wet cell (-5.9), the monitor phase through
    # more of it (-6.8); the leaf's own policy never reaches the closet, so never
    # steps on the wet floor (0). Its avoid of 0 bounds nothing: the avoid phase's
    # policy answers, the one that keeps both zero-slack edges by LAR's rule.
    returns = jnp.array([[79.18, -6.78, -98.21], [79.18, -5.90, -98.21],
                         [0.0, 0.0, -98.21]])
    held, order = jnp.array([True, True, False]), [2, 0, 1]
    edges, allowance = [(0, 1), (1, 2)], jnp.zeros(2)
    penalty = jnp.array([1.2, 0.0, 30.0])
    assert int(select_phase(returns, penalty, order, 10.0, held, edges=edges,
                            allowance=allowance)) == 1
    # Without the edges the leaf's avoid stands: the avoid phase is no candidate.
    assert int(select_phase(returns, penalty, order, 10.0, held)) == 0
    # A leaf that keeps the monitor's best bounds the avoid phase as before.
    kept = returns.at[2].set(jnp.array([79.18, -5.0, -98.21]))
    assert int(select_phase(kept, penalty.at[2].set(0.0), order, 10.0, held, edges=edges,
                            allowance=allowance)) == 2


def test_a_run_s_pick_holds_the_graph_s_edges_at_their_start_allowance():
    # A run's selection passes the graph's edges and each slack's start value to
    # select_phase:
    # the same G>M>A (100, 0) candidates as above, on the grid (no training).
    graph = ObjectiveGraph.parse("G>M>A", [100, 0], objectives=OBJECTIVES)
    trainer = Trainer(GridNav(load_map("small")), graph, TPOConfig(num_envs=4, num_steps=16),
                      3 * 64)
    slack = trainer.slack_array()
    assert selection.edges(trainer) == [(0, 1), (1, 2)]
    np.testing.assert_allclose(selection.allowance(trainer, slack), [10000.0, 0.0], rtol=1e-5)
    returns = jnp.array([[-32.4, 0.0, -16.3], [-100.0, 61.7, -16.3], [-100.0, 0.0, -16.3]])
    absolute = selection.absolute_tolerance(trainer, returns)
    assert absolute.tolist() == [0.5] * 3  # on a map, returns tie within 0.5
    assert int(selection.selected(trainer, slack, returns, jnp.zeros(3), absolute)) == 1


@pytest.fixture(scope="module")
def three_phases():
    env = GridNav(load_map("small"))
    graph = ObjectiveGraph.parse("M>A>G", [5, 5], objectives=OBJECTIVES)
    trainer = Trainer(env, graph, TPOConfig(num_envs=4, num_steps=16), 3 * 64)
    state = trainer.init(jax.random.key(0))
    actors = [trainer.init_params(jax.random.key(k))["actor"] for k in (1, 2, 3)]
    state = state.replace(snapshots=jax.tree.map(lambda *x: jnp.stack(x), *actors))
    return env, trainer, state, actors


def test_candidates_are_each_snapshot_s_greedy_returns_and_penalty(three_phases):
    env, trainer, state, actors = three_phases
    slack = trainer.slack_array()
    returns, penalty = jax.jit(lambda st, sl: selection.candidates(trainer, st, sl, env))(
        state, slack)
    keys = jax.random.split(jax.random.fold_in(state.key, 1), SELECT_EPISODES)
    columns = [OBJECTIVES.index(n) for n in ("monitor", "avoid", "goal")]
    for p, actor in enumerate(actors):
        acting = trainer.acting(state, slack)._replace(actor=actor)
        _, disc, _ = episode_returns(trainer.policy, acting, env, keys, True, 0.99)
        np.testing.assert_allclose(returns[p], disc.mean(0)[jnp.array(columns)], rtol=1e-5,
                                   atol=1e-4)
    assert penalty.shape == (3,) and bool((penalty >= 0).all())


def test_select_answers_with_the_selected_snapshot_once_and_for_all(three_phases):
    env, trainer, state, actors = three_phases
    slack = trainer.slack_array()
    finish = jax.jit(lambda st, sl: select(trainer, st, sl, env))
    done = finish(state, slack)
    chosen = [p for p, a in enumerate(actors)
              if jax.tree.all(jax.tree.map(jnp.array_equal, a, done.params["actor"]))]
    assert len(chosen) == 1
    again = finish(done, slack)
    assert jax.tree.all(jax.tree.map(jnp.array_equal, again.params["actor"],
                                     done.params["actor"]))
    off = Trainer(env, trainer.problem.graph, TPOConfig(num_envs=4, num_steps=16, select=False),
                  3 * 64)
    kept = select(off, state, slack, env)
    assert kept.params["actor"] is state.params["actor"]


def test_a_population_answers_with_the_member_and_snapshot_its_returns_pick(three_phases):
    env, trainer, state, _ = three_phases
    slack = trainer.slack_array()
    # Two members: the fixture's, and one whose snapshots come in reverse order.
    other = state.replace(snapshots=jax.tree.map(lambda x: x[::-1], state.snapshots),
                          update=state.update + 1)
    states = jax.tree.map(lambda *x: jnp.stack(x), state, other)
    done = jax.jit(lambda st, sl: select(trainer, st, sl, env))(states, slack)
    returns, penalty = jax.vmap(lambda s: selection.candidates(trainer, s, slack, env))(states)
    picks = jax.vmap(lambda r, p: selection.selected(trainer, slack, r, p, 0.5))(returns,
                                                                                       penalty)
    m = int(select_member(returns, picks, [(0, 1), (1, 2)], slack / 0.01, ORDER))
    assert int(done.update) == m  # the chosen member's own state ...
    snapshot = jax.tree.map(lambda x: x[m, int(picks[m])], states.snapshots)
    assert jax.tree.all(jax.tree.map(jnp.array_equal, snapshot, done.params["actor"]))
    # ... acting with its answer.


def test_every_phase_leaves_its_final_actor_in_the_snapshots():
    env = GridNav(load_map("small"), random_start=True)
    graph = ObjectiveGraph.parse("M>A>G", [5, 5], objectives=OBJECTIVES)
    trainer = Trainer(env, graph, TPOConfig(num_envs=4, num_steps=16), 3 * 2 * 64)
    slack = trainer.slack_array()
    state = trainer.init(jax.random.key(0))
    run = jax.jit(trainer.run, static_argnums=2)
    ends = []
    for _ in range(3):  # two updates a phase
        state, _ = run(state, slack, 2)
        ends.append(state.params["actor"])
    for p, actor in enumerate(ends):
        assert jax.tree.all(jax.tree.map(
            lambda s, a, p=p: jnp.array_equal(s[p], a), state.snapshots, actor))
    first = [jax.tree.leaves(a)[0] for a in ends]
    assert not np.array_equal(first[0], first[1]) and not np.array_equal(first[1], first[2])


@pytest.mark.parametrize("batch", [(), (2, 3)])
def test_a_format_5_state_loads_with_its_actor_as_every_snapshot(three_phases, batch):
    """States saved before snapshots (a model, or a sweep's [slack, seed] stack)."""
    _, _, state, _ = three_phases
    state = jax.tree.map(lambda x: jnp.broadcast_to(x, (*batch, *x.shape)), state)
    data = serialization.to_state_dict(state.replace(key=jax.random.key_data(state.key)))
    del data["snapshots"]
    blob = serialization.msgpack_serialize({"format": 5, "state": data})
    loaded, _ = restore_state(state, blob)
    axis = len(batch)
    jax.tree.map(lambda s, a: np.testing.assert_array_equal(
        s, np.stack([a] * 3, axis)), loaded.snapshots, state.params["actor"])
    np.testing.assert_array_equal(loaded.design, np.zeros(batch, np.int32))
    np.testing.assert_array_equal(loaded.view, np.zeros(batch, np.int32))


def test_a_format_6_state_learned_the_first_design_on_the_whole_observation(three_phases):
    """States saved before a population's mixed members (whatever the template's)."""
    _, _, state, _ = three_phases
    data = serialization.to_state_dict(state.replace(key=jax.random.key_data(state.key)))
    del data["design"], data["view"]
    blob = serialization.msgpack_serialize({"format": 6, "state": data})
    loaded, _ = restore_state(state.replace(design=jnp.int32(1), view=jnp.int32(1)), blob)
    assert int(loaded.design) == 0 and int(loaded.view) == 0
    jax.tree.map(np.testing.assert_array_equal, loaded.snapshots, state.snapshots)


def test_a_gymnasium_env_s_run_is_finished_on_the_host_alike():
    """select on a HostRunner: the same scores from episodes stepped on the host."""
    model = TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure>time", slack=0.0,
                objectives=["treasure", "time"],
                config=TPOConfig(num_envs=4, num_steps=16)).learn(2 * 64 * 2)
    state, trainer, runner = model.state, model.trainer, model._run
    chosen = [p for p in range(2) if jax.tree.all(jax.tree.map(
        lambda s, a, p=p: jnp.array_equal(s[p], a), state.snapshots, state.params["actor"]))]
    assert len(chosen) == 1  # the run ended by selecting a snapshot
    acting = trainer.acting(state, trainer.slack_array(), jnp.int32(trainer.problem.reference))
    ep = runner.greedy_episodes(acting, 6, seed=0)
    assert ep.obs.shape[0] == 6 and ep.obs.shape[1] >= int(ep.alive.sum(1).max())
    returns, _ = jax.jit(lambda *a: selection.score(trainer, *a))(state, trainer.slack_array(),
                                                                   ep)
    mc = runner.monte_carlo(acting, 6, True, trainer.config.gamma, 0)["discounted"]
    # phases (treasure, time) are the env's reward columns (treasure, time)
    np.testing.assert_allclose(returns, mc.mean(0), rtol=1e-5, atol=1e-5)


# select_member: a population's answers, M>A>G at (100, 0) on held2 (numbers from a
# run: the goal phase's policy of member 0 crosses one wet cell, avoid -0.9).
EDGES = [(0, 1), (1, 2)]  # monitor -> avoid, avoid -> goal
MEMBERS = [[[76.1, -3.7, -86.6], [0.0, 0.0, -86.6], [0.0, -0.9, -20.6]],
           [[76.1, -3.7, -86.6], [0.0, 0.0, -86.6], [0.0, 0.0, -25.3]]]


def member(returns, picks, allowance):
    return int(select_member(jnp.array(returns, jnp.float32), jnp.array(picks),
                             EDGES, jnp.array(allowance, jnp.float32), ORDER))


def test_a_member_that_loses_a_zero_slack_parent_s_best_does_not_answer():
    # The best avoid of any policy that keeps the monitor within 100 is 0; at zero
    # slack the answer must keep it (within the judge's 0.5), whatever its goal.
    assert member(MEMBERS, [2, 2], [100.0, 0.0]) == 1
    # With slack on avoid -> goal, the better goal answers.
    assert member(MEMBERS, [2, 2], [100.0, 1.0]) == 0
    # The allowance is the start value's: a local slack over 1 - gamma.
    assert member(MEMBERS, [2, 2], [100.0, 0.4]) == 0


def test_the_best_parent_value_comes_from_every_candidate_keeping_its_own_edges():
    # With no slack on monitor -> avoid, only policies keeping the monitor at 76.1
    # count for the avoid's best (-3.7): both answers keep it, so the goal decides.
    weak = [[[76.1, -3.7, -86.6], [0.0, 0.0, -86.6], [76.1, -3.7, -30.0]],
            [[76.1, -3.7, -86.6], [0.0, 0.0, -86.6], [76.1, -3.7, -40.0]]]
    assert member(weak, [2, 2], [0.0, 0.0]) == 0
    # An answer that loses the root's best is no answer while another keeps it.
    weak[0][2][0] = 70.0
    assert member(weak, [2, 2], [0.0, 0.0]) == 1


def test_members_tie_as_the_judge_does_and_none_keeping_the_edges_falls_back():
    both_wet = [MEMBERS[0], MEMBERS[0][:2] + [[0.0, -0.9, -21.0]]]
    # Neither keeps the avoid's 0: the better goal answers (-20.6 against -21.0).
    assert member(both_wet, [2, 2], [100.0, 0.0]) == 0
    # Goals within 2 %: the monitor, then the avoid decide, roots first; then the first.
    tied = [[[0.0] * 3, [0.0] * 3, [1.0, -1.0, -25.0]], [[0.0] * 3, [0.0] * 3, [1.0, 0.0, -25.3]]]
    assert member(tied, [2, 2], [100.0, 100.0]) == 1
    assert member([tied[0], tied[0]], [2, 2], [100.0, 100.0]) == 0
    # A member's answer is the candidate its pick names: member 1's avoid policy keeps
    # the avoid's 0 where member 0's answer does not.
    assert member(MEMBERS, [2, 1], [100.0, 0.0]) == 1
    assert member(MEMBERS, [2, 1], [100.0, 1.0]) == 0
