"""A smoothing filter stage in Python, between the kinematics networks and the optimizer.

Each frame of KinematicsFrame is blended with the filter's previous output: joint positions and
velocities and the root velocity by an exponential moving average, joint rotations by normalized
linear interpolation on the same hemisphere; contact and stationary probabilities and gravity
pass through. `alpha` (params, default 0.5) is the weight of the new frame: 1 passes it through.

    [stages.smooth]
    exec = "python3"                              # or a virtual environment's bin/python
    args = ["python/examples/smooth.py"]
    inputs = { kin = "kin.kinematics" }
    outputs = { kinematics = "KinematicsFrame" }
    params = { alpha = 0.5 }
"""

import numpy as np

import imuflow

BLENDED = ("joint_position_m", "joint_velocity_mps", "root_velocity_mps")
PASSED = ("foot_contact_prob", "stationary_prob", "gravity_in_root_mps2")


def blend_rotations(previous, new, alpha):
    """Per joint: nlerp from `previous` to `new` (wxyz, (24, 4)) by `alpha`, taking the shorter
    way (q and -q are the same rotation)."""
    sign = np.where(np.sum(previous * new, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    q = (1 - alpha) * previous + alpha * sign * new
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def main():
    stage = imuflow.Stage.from_env()
    stage.input("kin", "KinematicsFrame")
    out = stage.output("kinematics", "KinematicsFrame")
    alpha = float(stage.params.get("alpha", 0.5))
    if not 0 < alpha <= 1:
        raise imuflow.StageError(f"stage '{stage.id}': params.alpha = {alpha} must be in (0, 1]")
    if not stage.ready():
        return
    state = None  # the previous output: rotations and the blended fields
    for step in stage:
        kin = step["kin"]
        if state is None:
            state = {"local_pose_wxyz": np.array(kin["local_pose_wxyz"])}
            state.update({name: np.array(kin[name]) for name in BLENDED})
        else:
            state["local_pose_wxyz"] = blend_rotations(state["local_pose_wxyz"],
                                                       kin["local_pose_wxyz"], alpha)
            for name in BLENDED:
                state[name] = (1 - alpha) * state[name] + alpha * kin[name]
        frame = out.loan(step)
        for name, value in state.items():
            frame[name] = value
        for name in PASSED:
            frame[name] = kin[name]
        out.send(frame)
    stage.finish()


if __name__ == "__main__":
    main()
