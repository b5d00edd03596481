"""Exact policy evaluation and the exact policy gradient (paper Prop. 3, Eq. 8).

Every function here solves the linear Bellman equation of a fixed policy
exactly (a sparse LU factorisation of ``I - gamma P_pi``), for every objective
at once.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tpo.errors import ModelError
from tpo.tabular.model import TabularTMDP, policy_probs


def _rewards(model: TabularTMDP, rewards: np.ndarray | None) -> np.ndarray:
    """Reward columns ``[S, A, m]``: the model's, or a user's ``[S, A]`` / ``[S, A, m]``."""
    if rewards is None:
        return model.rewards
    r = np.asarray(rewards, dtype=np.float64)
    if r.ndim == 2:
        r = r[:, :, None]
    if r.ndim != 3 or r.shape[:2] != (model.n_states, model.n_actions):
        raise ModelError(f"rewards must be [S, A] or [S, A, m], got shape {np.shape(rewards)}")
    return r


def _factor(model: TabularTMDP, pi: np.ndarray) -> spla.SuperLU:
    """LU factors of ``I - gamma P_pi``."""
    eye = sp.identity(model.n_states, format="csr")
    return spla.splu((eye - model.gamma * model.policy_matrix(pi)).tocsc())


def evaluate_policy(model: TabularTMDP, policy: np.ndarray,
                    rewards: np.ndarray | None = None) -> np.ndarray:
    """``V^pi[s, i]`` of a deterministic ``[S]`` or stochastic ``[S, A]`` policy.

    Solves ``(I - gamma P_pi) V = R_pi`` exactly, with ``V = 0`` at terminal states.
    ``rewards`` (``[S, A]`` or ``[S, A, m]``) replaces the model's reward columns.
    A deterministic policy in a deterministic model is evaluated by pointer
    jumping (:func:`evaluate_paths`), any other by a sparse LU solve.
    """
    pi = policy_probs(policy, model.n_states, model.n_actions)
    r_pi = np.einsum("sa,sam->sm", pi, _rewards(model, rewards))
    r_pi[model.terminal] = 0.0
    if model.deterministic and np.ndim(policy) == 1:
        successor = model.successors[np.arange(model.n_states), policy, 0]
        return evaluate_paths(successor, r_pi, model.gamma)
    return _factor(model, pi).solve(r_pi)


def evaluate_paths(successor: np.ndarray, reward: np.ndarray, gamma: float) -> np.ndarray:
    """``V(s) = sum_t gamma^t r(s_t)`` along ``s_{t+1} = successor[s_t]``, by pointer jumping.

    After ``j`` doublings ``acc`` holds the first ``2^j`` discounted rewards and
    ``ptr`` the state ``2^j`` steps ahead, so ``O(S log H)`` work reaches the
    horizon ``H`` where ``gamma^H < 1e-17``: exact to float64 precision.
    """
    acc = np.array(reward, dtype=np.float64)
    ptr = np.asarray(successor)
    discount = gamma
    while discount > 1e-17:
        acc += discount * acc[ptr]
        ptr = ptr[ptr]
        discount *= discount
    return acc


def q_values(model: TabularTMDP, values: np.ndarray,
             rewards: np.ndarray | None = None) -> np.ndarray:
    """``Q[s, a, i] = R_i(s, a) + gamma E[V_i(s')]`` from values ``[S, m]``."""
    r = _rewards(model, rewards)
    q = r + model.gamma * model.expect(values)
    q[model.terminal] = 0.0
    return q


def discounted_visitation(model: TabularTMDP, policy: np.ndarray) -> np.ndarray:
    """``d^pi(s) = sum_t gamma^t Pr(s_t = s | s_0, pi)`` from the model's start state."""
    pi = policy_probs(policy, model.n_states, model.n_actions)
    start = np.zeros(model.n_states)
    start[model.start] = 1.0
    return _factor(model, pi).solve(start, trans="T")


def softmax(logits: np.ndarray) -> np.ndarray:
    """Row-wise softmax of ``[S, A]`` logits."""
    z = np.exp(logits - logits.max(axis=1, keepdims=True))
    return z / z.sum(axis=1, keepdims=True)


def policy_gradient(model: TabularTMDP, logits: np.ndarray,
                    rewards: np.ndarray | None = None) -> np.ndarray:
    """Exact gradient ``d V_i^pi(s0) / d theta`` of a tabular softmax policy (Eq. 8).

    With ``pi(a|s) = softmax(theta[s])_a``, Eq. 8
    ``sum_s d^pi(s) sum_a dpi(a|s)/dtheta Q_i^pi(s, a)`` becomes
    ``grad[i, s, b] = d^pi(s) pi(b|s) (Q_i^pi(s, b) - V_i^pi(s))``.
    Pass Lagrangian rewards ``R_i - beta C`` as ``rewards`` for the gradient of
    the Lagrangian objective (Prop. 3). Returns ``[m, S, A]``.
    """
    logits = np.asarray(logits, dtype=np.float64)
    if logits.shape != (model.n_states, model.n_actions) or not np.all(np.isfinite(logits)):
        raise ModelError(f"logits must be finite [S={model.n_states}, A={model.n_actions}], "
                         f"got shape {logits.shape}")
    pi = softmax(logits)
    r = _rewards(model, rewards)
    lu = _factor(model, pi)
    r_pi = np.einsum("sa,sam->sm", pi, r)
    r_pi[model.terminal] = 0.0
    v = lu.solve(r_pi)
    start = np.zeros(model.n_states)
    start[model.start] = 1.0
    d = lu.solve(start, trans="T")
    q = q_values(model, v, r)
    adv = q - v[:, None, :]
    return np.moveaxis(d[:, None, None] * pi[:, :, None] * adv, 2, 0)
