#!/usr/bin/env python3
"""Independent check of imuflow-body's rigid-body dynamics against Pinocchio.

Usage: check_dynamics.py DIR   (DIR holds body.urdf and dynamics.json from
`cargo run --release -p imuflow-body --example dump_dynamics -- DIR`).

1. Builds a pinocchio.Model from the exported URDF read with xml.etree: a JointModelFreeFlyer root and one
   JointModelSpherical per SMPL joint (URDF has no spherical joint, so each triple of continuous joints
   `name_rx/_ry/_rz` is merged: placement = origin of `name_rx`, body = inertial of link `name`). Armature
   and gravity come from the JSON (URDF cannot hold armature).
2. Converts our coordinates to Pinocchio's: free-flyer linear velocity is in the root frame (ours: world),
   so v_pin = T v with T = blockdiag(R0^T, I); configuration = quaternions (x, y, z, w).
   Then M = T^T M_pin T and h = T^T rnea(q, v_pin, a_pin) with a_pin = dT/dt v (v' = 0): the linear part
   is -w0 x v_pin_lin.
3. Compares M (pin.crba, upper triangle mirrored), h (pin.rnea), point Jacobians and J'v (frames on the
   joints) for random states, to 1e-6.
4. Also loads the URDF with Pinocchio's own parser (Euler-angle chains): at states with identity joint
   rotations the chains' velocity coordinates coincide with ours, so M and the gravity forces must agree
   there too; and the total mass must match.
Exits 1 on any mismatch.
"""

import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

TOL = 1e-6


def vec(text):
    return np.array([float(x) for x in text.split()])


def parse_urdf(path):
    root = ET.parse(path).getroot()
    links = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            links[link.get("name")] = None
            continue
        origin = inertial.find("origin")
        com = vec(origin.get("xyz")) if origin is not None else np.zeros(3)
        if origin is not None and np.any(vec(origin.get("rpy", "0 0 0")) != 0):
            raise ValueError("rotated inertial frames are not supported")
        mass = float(inertial.find("mass").get("value"))
        i = inertial.find("inertia").attrib
        inertia = np.array(
            [
                [float(i["ixx"]), float(i["ixy"]), float(i["ixz"])],
                [float(i["ixy"]), float(i["iyy"]), float(i["iyz"])],
                [float(i["ixz"]), float(i["iyz"]), float(i["izz"])],
            ]
        )
        links[link.get("name")] = (mass, com, inertia)
    joints = {}
    for joint in root.findall("joint"):
        origin = joint.find("origin")
        axis = joint.find("axis")
        joints[joint.get("name")] = {
            "type": joint.get("type"),
            "parent": joint.find("parent").get("link"),
            "child": joint.find("child").get("link"),
            "xyz": vec(origin.get("xyz")) if origin is not None else np.zeros(3),
            "rpy": vec(origin.get("rpy", "0 0 0")) if origin is not None else np.zeros(3),
            "axis": vec(axis.get("xyz")) if axis is not None else None,
        }
    return links, joints


def spherical_model(urdf, dump):
    """Free-flyer + spherical joints from the URDF.

    Joints are added depth-first: Pinocchio requires it (its CRBA assumes every subtree's DoFs are
    contiguous, as its URDF parser produces; stack-of-tasks/pinocchio#1897) and silently returns a wrong M
    for SMPL's breadth-first index order (seen with pin 4.1.0: crba disagreed with rnea and
    computeKineticEnergy by up to 270). `perm[our_dof]` is the matching Pinocchio velocity index.
    """
    links, joints = parse_urdf(urdf)
    model = pin.Model()
    names = dump["joints"]
    root = next(j for j in joints.values() if j["type"] == "floating")
    assert root["child"] == names[0], "floating joint must carry the root link"
    children = {}
    for name in names[1:]:
        rx, ry, rz = (joints[f"{name}_{s}"] for s in ("rx", "ry", "rz"))
        # The triple must be a pure x-y-z chain at one point with massless links in between.
        for j, axis in ((rx, [1, 0, 0]), (ry, [0, 1, 0]), (rz, [0, 0, 1])):
            assert j["type"] in ("continuous", "revolute") and np.allclose(j["axis"], axis), name
            assert np.all(j["rpy"] == 0), name
        assert np.all(ry["xyz"] == 0) and np.all(rz["xyz"] == 0), name
        assert rx["child"] == ry["parent"] and ry["child"] == rz["parent"] and rz["child"] == name
        assert links[rx["child"]] is None and links[ry["child"]] is None, name
        children.setdefault(rx["parent"], []).append((name, rx["xyz"]))
    ids = {names[0]: model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root")}

    def add_subtree(parent):
        for name, xyz in children.get(parent, []):
            ids[name] = model.addJoint(ids[parent], pin.JointModelSpherical(), pin.SE3(np.eye(3), xyz), name)
            add_subtree(name)

    add_subtree(names[0])
    assert len(ids) == len(names)
    for name in names:
        body = links[name]
        if body is not None:
            mass, com, inertia = body
            model.appendBodyToJoint(ids[name], pin.Inertia(mass, com, inertia), pin.SE3.Identity())
    perm = np.zeros(model.nv, dtype=int)
    perm[0:6] = model.idx_vs[ids[names[0]]] + np.arange(6)
    for k, name in enumerate(names[1:], start=1):
        perm[3 + 3 * k : 6 + 3 * k] = model.idx_vs[ids[name]] + np.arange(3)
    assert sorted(perm) == list(range(model.nv))
    model.gravity = pin.Motion(np.array(dump["gravity"]), np.zeros(3))
    armature = np.zeros(model.nv)
    for k, a in enumerate(dump["armature_kgm2"]):
        armature[perm[3 + 3 * k : 6 + 3 * k]] = a
    model.armature = armature
    return model, ids, perm


def state(dump_state, model, ids, names, perm):
    """Pinocchio q, v, a (v' = 0) and T for one of our states; vectors in Pinocchio's DoF order."""
    n = model.nv
    rots = [np.array(r).reshape(3, 3) for r in dump_state["rotations_row_major"]]
    q = np.zeros(model.nq)
    iq = model.idx_qs[ids[names[0]]]
    q[iq : iq + 3] = dump_state["root_position"]
    for k, name in enumerate(names):
        iq = model.idx_qs[ids[name]] + (3 if k == 0 else 0)
        q[iq : iq + 4] = pin.Quaternion(rots[k]).coeffs()  # (x, y, z, w)
    v = np.array(dump_state["v"])
    T = np.eye(n)
    T[0:3, 0:3] = rots[0].T
    v_pin = np.zeros(n)
    v_pin[perm] = T @ v
    a_pin = np.zeros(n)
    a_pin[perm[0:3]] = -np.cross(v[3:6], (T @ v)[0:3])
    return rots, q, v_pin, a_pin, T


def full(m):
    return np.triu(m) + np.triu(m, 1).T


def main():
    d = Path(sys.argv[1] if len(sys.argv) > 1 else "out/dynamics")
    dump = json.loads((d / "dynamics.json").read_text())
    urdf = d / "body.urdf"
    model, ids, perm = spherical_model(urdf, dump)
    names = dump["joints"]
    frames = []
    for k, p in enumerate(dump["points"]):
        name = dump["joints"][p["joint"]]
        placement = pin.SE3(np.eye(3), np.array(p["point"]))
        frame = pin.Frame(f"point{k}", ids[name], placement, pin.FrameType.OP_FRAME)
        frames.append(model.addFrame(frame))
    data = model.createData()
    n = model.nv
    assert n == 75

    err = {"M": 0.0, "h": 0.0, "gravity_h": 0.0, "J": 0.0, "jdot_v": 0.0, "position": 0.0}
    scale = {"M": 0.0, "h": 0.0}
    for s in dump["states"]:
        rots, q, v_pin, a_pin, T = state(s, model, ids, names, perm)
        M = T.T @ full(pin.crba(model, data, q))[np.ix_(perm, perm)] @ T
        h = T.T @ pin.rnea(model, data, q, v_pin, a_pin)[perm]
        g = T.T @ pin.computeGeneralizedGravity(model, data, q)[perm]
        ours_M, ours_h = np.array(s["M"]), np.array(s["h"])
        err["M"] = max(err["M"], np.abs(M - ours_M).max())
        err["h"] = max(err["h"], np.abs(h - ours_h).max())
        err["gravity_h"] = max(err["gravity_h"], np.abs(g - np.array(s["gravity_h"])).max())
        scale["M"] = max(scale["M"], np.abs(M).max())
        scale["h"] = max(scale["h"], np.abs(h).max())
        pin.forwardKinematics(model, data, q, v_pin, a_pin)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        for fid, ps in zip(frames, s["points"]):
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3, perm] @ T
            acc = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
            err["J"] = max(err["J"], np.abs(J - np.array(ps["J"])).max())
            err["jdot_v"] = max(err["jdot_v"], np.abs(acc - np.array(ps["jdot_v"])).max())
            pos_err = np.abs(data.oMf[fid].translation - np.array(ps["position"])).max()
            err["position"] = max(err["position"], pos_err)

    # Pinocchio's own URDF parser (floating root, Euler-angle chains of continuous joints).
    urdf_model = pin.buildModelFromUrdf(str(urdf))
    urdf_model.gravity = pin.Motion(np.array(dump["gravity"]), np.zeros(3))
    # Our DoF index -> the URDF model's velocity index.
    urdf_perm = np.zeros(n, dtype=int)
    root_id = urdf_model.getJointId("root")
    assert urdf_model.joints[root_id].nv == 6, "the URDF root must load as a free flyer"
    urdf_perm[0:6] = urdf_model.idx_vs[root_id] + np.arange(6)
    armature = np.zeros(urdf_model.nv)
    armature[urdf_perm[3:6]] = dump["armature_kgm2"][0]
    for k, name in enumerate(dump["joints"][1:], start=1):
        for a, axis in enumerate(("rx", "ry", "rz")):
            urdf_perm[3 + 3 * k + a] = urdf_model.idx_vs[urdf_model.getJointId(f"{name}_{axis}")]
            armature[urdf_perm[3 + 3 * k + a]] = dump["armature_kgm2"][k]
    urdf_model.armature = armature
    urdf_data = urdf_model.createData()
    err["urdf_parser_M"] = 0.0
    err["urdf_parser_gravity_h"] = 0.0
    for s in dump["states"][: dump["identity_states"]]:
        rots, _, _, _, T = state(s, model, ids, names, perm)
        q = pin.neutral(urdf_model)  # all joint angles 0 (continuous joints: cos = 1, sin = 0)
        iq = urdf_model.idx_qs[root_id]
        q[iq : iq + 3] = s["root_position"]
        q[iq + 3 : iq + 7] = pin.Quaternion(rots[0]).coeffs()
        M = full(pin.crba(urdf_model, urdf_data, q))[np.ix_(urdf_perm, urdf_perm)]
        g = pin.computeGeneralizedGravity(urdf_model, urdf_data, q)[urdf_perm]
        err["urdf_parser_M"] = max(err["urdf_parser_M"], np.abs(T.T @ M @ T - np.array(s["M"])).max())
        err["urdf_parser_gravity_h"] = max(
            err["urdf_parser_gravity_h"], np.abs(T.T @ g - np.array(s["gravity_h"])).max()
        )
    mass_err = abs(pin.computeTotalMass(urdf_model) - dump["total_mass_kg"])
    err["total_mass"] = max(mass_err, abs(dump["total_mass_kg"] - dump["mass_kg"]))
    # Kinetic energy through a different Pinocchio code path, and the contiguity assumption itself.
    err["kinetic_energy"] = 0.0
    for s in dump["states"]:
        rots, q, v_pin, _, T = state(s, model, ids, names, perm)
        v = np.array(s["v"])
        ke = pin.computeKineticEnergy(model, data, q, v_pin)
        err["kinetic_energy"] = max(err["kinetic_energy"], abs(ke - 0.5 * v @ np.array(s["M"]) @ v))

    print(f"pinocchio {pin.__version__}; {len(dump['states'])} random states, {len(frames)} points each")
    print(f"  (max |M| = {scale['M']:.3g}, max |h| = {scale['h']:.3g})")
    ok = True
    for key, e in err.items():
        status = "ok" if e <= TOL else "FAIL"
        ok &= e <= TOL
        print(f"  max abs diff {key:24s} {e:.3e}  {status}")
    if not ok:
        print(f"dynamics check FAILED (tolerance {TOL})")
        sys.exit(1)
    print(f"dynamics check passed (tolerance {TOL})")


if __name__ == "__main__":
    main()
