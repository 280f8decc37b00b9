"""A URDF as an MJCF: MuJoCo's own URDF compiler reads it, and a motor is added on every joint.

Mesh geometry is dropped first (its `package://` paths name files MuJoCo cannot resolve, and identification
needs only the URDF's `<inertial>` elements); primitive geometry is kept, weightless on a link without an
`<inertial>` (a massless link, as the URDF means it). MuJoCo reads each joint's
`<limit effort>` as its `actuatorfrcrange`; the motor added on it gets that range as its ctrl range, so the
torque limit is the URDF's effort limit. Joint velocity limits, which MuJoCo ignores, are read here.
"""

from __future__ import annotations

import hashlib
import re
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

from dynamics.errors import ModelError, one_line

__all__ = ["URDF_SUFFIXES", "is_urdf", "mjcf_from_urdf", "urdf_as_mjcf_file", "urdf_velocity_limits"]

URDF_SUFFIXES = (".urdf",)


def is_urdf(path: Path) -> bool:
    """Whether `path` is a URDF: named `.urdf`, or any other file whose root element is `<robot>` (a URDF saved
    as `.xml`, which MuJoCo would compile without the actuators `mjcf_from_urdf` adds at its effort limits).
    The root element decides, before any fault further on (which the URDF reader then names); a file that does
    not begin as XML is not one."""
    if path.suffix.lower() in URDF_SUFFIXES:
        return True
    try:
        for _, element in ET.iterparse(path, events=("start",)):
            return element.tag.rsplit("}", 1)[-1] == "robot"  # with or without an XML namespace
    except (ET.ParseError, OSError):
        return False
    return False


def _stripped(path: Path) -> ET.Element:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise ModelError(f"{path}: not a readable URDF: {err}") from err
    if root.tag != "robot":
        raise ModelError(f"{path}: not a URDF (its root element is <{root.tag}>, not <robot>)")
    for joint in root.iter("joint"):
        if joint.get("type") == "planar":  # MuJoCo makes it two slides and a hinge, with no effort limit to drive them
            raise ModelError(
                f"{path}: joint {joint.get('name')!r} is planar (a link that moves freely in a plane, a mobile base): "
                "only revolute, continuous, prismatic and fixed joints are supported; make it fixed to identify the "
                "arm on it"
            )
        mimic = joint.find("mimic")
        if mimic is not None:  # MuJoCo makes it an <equality>, which the refusal would name in a temporary MJCF
            raise ModelError(
                f"{path}: joint {joint.get('name')!r} has a <mimic> of joint {mimic.get('joint')!r}: coupled joints "
                "are not supported (remove the <mimic> element to identify the joints independently)"
            )
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for element in list(link.findall(tag)):
                if element.find("geometry/mesh") is not None:
                    link.remove(element)
    return root


def _massless_links(spec: mujoco.MjSpec) -> list[str]:
    """The links without an `<inertial>`: massless, as the URDF means it (and Pinocchio reads it). MuJoCo would
    give them the mass of their primitive geometry at its default density (a 10 cm collision box: 1 kg); their
    geoms are made weightless instead. Returns their names."""
    out = []
    for body in spec.bodies:
        if body.name == "world" or body.explicitinertial:
            continue
        for geom in body.geoms:
            geom.density = 0.0
        out.append(body.name)
    return out


def mjcf_from_urdf(path: Path) -> str:
    """MJCF text of a URDF, compiled by MuJoCo, with a motor on every joint (ctrl range = effort limit).

    Raises:
        ModelError: unreadable URDF, or one MuJoCo cannot compile.
    """
    root = _stripped(path)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    except ValueError as err:
        raise ModelError(f"{path}: MuJoCo cannot compile the URDF: {one_line(err)}") from err
    massless = _massless_links(spec)
    try:
        m = spec.compile()
    except ValueError as err:
        element = re.search(r"Element name '([^']*)'", str(err))  # the body MuJoCo names, quoted
        if element and element.group(1) in massless and "mass and inertia of moving bodies" in str(err):
            raise ModelError(
                f"{path}: link {element.group(1)!r} has no <inertial> (no mass, as a URDF means it) and a joint "
                "moves it, which MuJoCo cannot simulate: give it an <inertial> (a small mass and inertia where it is a "
                "virtual link between two joints)"
            ) from err
        hint = (  # MuJoCo's own advice, without where a URDF takes it
            ' (in a URDF: <mujoco><compiler balanceinertia="true"/></mujoco> inside <robot>; it changes that '
            "link's inertia, so check the values first)"
            if "balanceinertia" in str(err)
            else ""
        )
        raise ModelError(f"{path}: MuJoCo cannot compile the URDF: {one_line(err)}{hint}") from err
    for j in range(m.njnt):
        if int(m.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        motor = spec.add_actuator()
        motor.name = f"{name}_motor"
        motor.target = name
        motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
        effort = float(np.max(np.abs(m.jnt_actfrcrange[j]))) if m.jnt_actfrclimited[j] else 0.0
        if effort > 0:
            motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            motor.ctrlrange = np.array([-effort, effort])
    spec.compile()
    header = f"<!-- Compiled by MuJoCo from {path.name} (meshes dropped; a motor per joint at its effort limit). -->\n"
    return header + spec.to_xml()


def urdf_velocity_limits(path: Path) -> dict[str, float]:
    """Each joint's `<limit velocity>` [rad/s or m/s], where the URDF gives one (> 0)."""
    out: dict[str, float] = {}
    for joint in _stripped(path).iter("joint"):
        limit = joint.find("limit")
        if limit is not None and float(limit.get("velocity", "0")) > 0:
            out[str(joint.get("name"))] = float(limit.get("velocity", "0"))
    return out


def urdf_as_mjcf_file(path: Path) -> Path:
    """The URDF's MJCF written to a cache folder named by its content (the file `load_plant` then reads)."""
    xml = mjcf_from_urdf(path)
    digest = hashlib.sha256(xml.encode()).hexdigest()[:12]
    folder = Path(tempfile.gettempdir()) / f"sysid_urdf_{digest}"
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{path.stem}.xml"
    if not out.is_file():
        tmp = folder / f".{path.stem}.{digest}.tmp"
        tmp.write_text(xml)
        tmp.replace(out)
    return out
