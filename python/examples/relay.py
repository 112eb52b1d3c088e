"""A pass-through stage: each frame of input `in` goes to output `out` unchanged (its header
aside: seq, capture time and flags of the step, publish time now). What `imuflow bench transport
--relay-exec "python3 python/examples/relay.py"` times: the cost of a Python stage in a graph.

    [stages.relay]
    exec = "python3"
    args = ["python/examples/relay.py"]
    inputs = { in = "kin.kinematics" }
    outputs = { out = "KinematicsFrame" }
"""

import imuflow


def main():
    stage = imuflow.Stage.from_env()
    stage.input("in")
    out = stage.output("out")
    if stage.ready():
        for step in stage:
            out.forward(step, step["in"])
    stage.finish()


if __name__ == "__main__":
    main()
