"""A job's settings as submit() takes them: the names of its choices, its camera vectors and its lighting."""

from __future__ import annotations

import os
from typing import Optional, Sequence, Tuple

from . import limits as L
from .errors import ArgumentError
from .proto import render_settings_pb2 as rs_pb

METHODS = {
    "gl": rs_pb.REPROJECTION_METHOD_GL,
    "cpu": rs_pb.REPROJECTION_METHOD_CPU,
    "exact": rs_pb.REPROJECTION_METHOD_EXACT,
}
COMBINE = {"fixed": rs_pb.COMBINE_RULE_FIXED, "variance": rs_pb.COMBINE_RULE_VARIANCE}
SAMPLERS = {
    "sobol-burley": rs_pb.SAMPLER_SOBOL_BURLEY,
    "independent": rs_pb.SAMPLER_INDEPENDENT,
}
# Russian roulette by name: the proto's RussianRouletteMode values, named by the rest of their
# names in lower case ("paper", "albedo", "off", "throughput", "reuse", "auto"). Only the mode is sent: the
# master fills in each mode's start depth, termination probability and depth cap from its own table
# (common/roulette.h), and a job that names none gets the master's default.
_RR_PREFIX = "RUSSIAN_ROULETTE_MODE_"
ROULETTE = {
    name[len(_RR_PREFIX) :].lower(): value
    for name, value in rs_pb.RussianRouletteMode.items()
    if value != rs_pb.RUSSIAN_ROULETTE_MODE_UNSPECIFIED
}


def vec3(name: str, v: Sequence[float]) -> rs_pb.Vec3:
    values = [L.real(name, x) for x in v]
    if len(values) != 3:
        raise ArgumentError(f"{name} must be three numbers x, y, z")
    return rs_pb.Vec3(x=values[0], y=values[1], z=values[2])


def lighting(
    environment, strength: Optional[float], rotation: float, sun: Optional[Sequence[float]]
) -> Tuple[Optional[rs_pb.EnvironmentLight], Optional[str], Optional[rs_pb.SunLight]]:
    """The job's environment (and the image path to bundle, if it is an image) and sun, as `epr
    submit --env --sun` reads them. The master checks the values' ranges."""
    env = image = None
    if environment is not None:
        env = rs_pb.EnvironmentLight(rotation_degrees=L.real("environment_rotation", rotation))
        if isinstance(environment, (str, os.PathLike)):
            image = os.fspath(environment)
        else:
            colour = [environment] * 3 if isinstance(environment, (int, float)) else list(environment)
            if len(colour) != 3:
                raise ArgumentError("environment is an image path, or a colour: one number (a grey) or three (r, g, b)")
            env.color.CopyFrom(vec3("environment", colour))
        if strength is not None:
            env.strength = L.real("environment_strength", strength)
    elif strength is not None or rotation:
        raise ArgumentError("environment_strength and environment_rotation need an environment")
    sun_pb = None
    if sun is not None:
        n = [L.real("sun", x) for x in sun]
        if len(n) not in (3, 4, 5, 7):
            raise ArgumentError(
                "sun is (dx, dy, dz[, angle_degrees[, irradiance or r, g, b]]): the direction towards the sun, its "
                "angular diameter (default 0.53) and its irradiance in W/m^2 (default 1)"
            )
        sun_pb = rs_pb.SunLight(direction=vec3("sun direction", n[:3]))
        if len(n) >= 4:
            sun_pb.angle_degrees = n[3]
        if len(n) >= 5:
            sun_pb.irradiance.CopyFrom(vec3("sun irradiance", n[4:] if len(n) == 7 else [n[4]] * 3))
    return env, image, sun_pb
