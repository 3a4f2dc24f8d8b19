"""One observation layout (issue 43, item 4): the env, the features, the dataset and the deploy loop agree on it."""

from __future__ import annotations

import math

import numpy as np

from omcrl.envs import make_env
from omcrl.envs.observation import KINEMATICS, PRIVILEGED, PRIVILEGED_DIM, STATE, STATE_DIM, pack_state


def test_the_layout_is_contiguous_and_named():
    assert STATE_DIM == 12 and PRIVILEGED_DIM == 6 and KINEMATICS == slice(0, 9)
    assert [STATE[k] for k in ("v", "omega", "theta", "goal")] == [slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)]
    assert PRIVILEGED == {"obstacle": slice(0, 3), "goal": slice(3, 6)}
    s = pack_state((1, 2, 3), (4, 5, 6), (7, 8, 9), (10, 11, 12))
    assert s.dtype == np.float32 and s.tolist() == list(range(1, 13))


def test_env_and_deploy_loop_fill_the_entries_the_layout_names():
    from omcrl.data.dataset import FIELDS
    from omcrl.deploy.loop import StateEstimator

    env = make_env("box-v2", seed=0, image_size=16)
    obs, info = env.reset(seed=0, options={"start": (0.0, 0.0, 0.3), "goal": (3.0, 1.0)})
    env.close()
    assert env.observation_space["state"].shape == (STATE_DIM,) and obs["privileged"].shape == (PRIVILEGED_DIM,)
    assert FIELDS["state"][1] == (STATE_DIM,) and FIELDS["privileged"][1] == (PRIVILEGED_DIM,)
    # The goal in the body frame is in both vectors, and θ holds the start's yaw.
    np.testing.assert_array_equal(obs["state"][STATE["goal"]], obs["privileged"][PRIVILEGED["goal"]])
    assert math.isclose(float(obs["state"][STATE["theta"]][2]), 0.3, abs_tol=1e-6)
    c, s = math.cos(0.3), math.sin(0.3)
    np.testing.assert_allclose(obs["state"][STATE["goal"]][:2], [c * 3 + s * 1, -s * 3 + c * 1], atol=1e-5)
    # The deploy loop's estimator writes the same entries from a pose.
    est = StateEstimator(goal=(3.0, 1.0), altitude=1.0)
    got = est.update(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.3]), 0.0)
    np.testing.assert_allclose(got[STATE["goal"]], obs["state"][STATE["goal"]], atol=1e-5)
    assert got[STATE["theta"]][2] == np.float32(0.3) and not got[STATE["v"]].any()
