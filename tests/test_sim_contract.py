"""The simulated workcell passes the backend contract every robot must pass (tests/contract.py)."""

import pytest

from robots import connect

contract = pytest.importorskip("contract", reason="tests/contract.py (the contract) is missing")


@pytest.mark.parametrize("check", contract.CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_sim_contract_panda_eye_in_hand(check):  # PyBullet's
    # 320x240 keeps the camera check quick; the robot checks do not depend on it.
    check(lambda: connect("sim", engine="pybullet", arm="panda", mount="eye_in_hand", seed=0,
                          width=320, height=240))


@pytest.mark.parametrize("check", contract.CONTRACT_CHECKS, ids=lambda c: c.__name__)
def test_mujoco_contract_panda_eye_in_hand(check):
    pytest.importorskip("mujoco", reason="the MuJoCo engine needs `pip install mujoco`")
    check(lambda: connect("sim", engine="mujoco", arm="panda", mount="eye_in_hand", seed=0,
                          width=320, height=240))


@pytest.mark.parametrize("arm", ["ur5e", "aubo_i5"])
def test_sim_contract_other_arms_eye_to_hand(arm):
    # On MuJoCo; the Panda's contract above is PyBullet's slice.
    pytest.importorskip("mujoco", reason="the MuJoCo engine needs `pip install mujoco`")
    options = dict(engine="mujoco", arm=arm, mount="eye_to_hand", seed=1, width=320, height=240)
    contract.check_pose_round_trip(lambda: connect("sim", **options))
    contract.check_camera_frame(lambda: connect("sim", **options))
