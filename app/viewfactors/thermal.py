"""The thermal inputs of `radiosity heat`: each facet's emissivity and either its temperature
or its heat flux, and the environment's temperature, from a scene TOML ([material.NAME],
[[mesh]] entries, [environment], [heat]) and the command's options (defaults for what the file
leaves out; a plain mesh takes them for every facet). Keys: docs/src/reference/scenes.md.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from radiosity.errors import SceneError
from radiosity.viewfactors.facets import Facets

#: The keys a [material.NAME] table or a [[mesh]] entry may set for the heat command.
HEAT_KEYS = ("emissivity", "temperature_K", "heat_flux_W_m2")
ENVIRONMENT_KEYS = ("temperature_K",)
HEAT_TABLE_KEYS = ("length_unit_m",)


@dataclass(frozen=True)
class ThermalDefaults:
    """What the options give (None: not given): every facet's emissivity, temperature (K) or
    heat flux (W m^-2, positive leaving), unless the scene file sets its own; the
    environment's temperature (K, default 0: deep space)."""

    emissivity: float | None = None
    temperature_K: float | None = None
    heat_flux_W_m2: float | None = None
    environment_K: float | None = None


@dataclass(frozen=True)
class HeatInputs:
    """Per facet (n,), load order: emissivity float64 in (0, 1], fixed_t bool (a fixed
    temperature; else a fixed heat flux), temperature_K float64 (NaN where the flux is fixed),
    heat_flux float64 W m^-2 (0 where the temperature is fixed), material int32 index into
    material_names; environment_K; length_unit_m (mesh units to metres)."""

    emissivity: np.ndarray
    fixed_t: np.ndarray
    temperature_K: np.ndarray
    heat_flux: np.ndarray
    material: np.ndarray
    material_names: tuple
    environment_K: float
    length_unit_m: float = 1.0


#: How the options name the keys (the CLI flag, the Python keyword).
OPTION_NAMES = {"emissivity": "--emissivity (emissivity=)",
                "temperature_K": "--temperature (temperature_K=)",
                "heat_flux_W_m2": "--heat-flux (heat_flux_W_m2=)",
                "environment_K": "--environment-temperature (environment_K=)"}


def _check(where: str, vals: dict, names: dict | None = None) -> dict:
    """`vals` (the HEAT_KEYS a table sets) checked: finite numbers, emissivity in (0, 1],
    kelvins >= 0, not both a temperature and a flux. where: the file and table ("" for the
    options); names: how to name each key (OPTION_NAMES for the options)."""
    def say(k):
        return f"{where} {(names or {}).get(k, k)}".strip()

    out = {}
    for k, v in vals.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SceneError(f"{say(k)} = {v!r} must be a finite number")
        out[k] = float(v)
    if "emissivity" in out and not 0 < out["emissivity"] <= 1:
        raise SceneError(f"{say('emissivity')} = {out['emissivity']:g} must be in (0, 1]")
    for k in ("temperature_K", "environment_K"):
        if k in out and out[k] < 0:
            raise SceneError(f"{say(k)} = {out[k]:g} is negative (absolute temperature, kelvin)")
    if "temperature_K" in out and "heat_flux_W_m2" in out:
        raise SceneError(f"{say('temperature_K')} and {(names or {}).get('heat_flux_W_m2', 'heat_flux_W_m2')} "
                         "are both set: give one (heat_flux_W_m2 = 0 for a reradiating, adiabatic "
                         "surface)")
    return out


def _resolve(levels: list, where: str, name: str) -> tuple:
    """(emissivity, temperature or None, flux or None) from `levels`, most specific first
    (dicts of checked values): emissivity from the first that sets it; temperature and flux
    together, from the first that sets either."""
    e = next((lv["emissivity"] for lv in levels if "emissivity" in lv), None)
    tq = next((lv for lv in levels if "temperature_K" in lv or "heat_flux_W_m2" in lv), None)
    if e is None:
        raise SceneError(f"{where}: material '{name}' has no emissivity: set [material.{name}] "
                         "emissivity (or --emissivity for every facet)")
    if tq is None:
        raise SceneError(f"{where}: material '{name}' has neither temperature_K nor "
                         f"heat_flux_W_m2: set one in [material.{name}] (heat_flux_W_m2 = 0 for "
                         "a reradiating surface), or --temperature / --heat-flux")
    return e, tq.get("temperature_K"), tq.get("heat_flux_W_m2")


def _defaults_dict(d: ThermalDefaults) -> dict:
    names = (*HEAT_KEYS, "environment_K")
    return _check("", {k: getattr(d, k) for k in names if getattr(d, k) is not None},
                  OPTION_NAMES)


def _table(doc: dict, key: str, allowed: tuple, path: str) -> dict:
    t = doc.get(key, {})
    if not isinstance(t, dict):
        raise SceneError(f"{path}: [{key}] must be a table")
    unknown = set(t) - set(allowed)
    if unknown:
        raise SceneError(f"{path}: [{key}] has unknown key(s) {sorted(unknown)}; allowed: "
                         f"{list(allowed)}")
    return t


def heat_inputs(mesh, fac: Facets, defaults: ThermalDefaults) -> HeatInputs:
    """The HeatInputs of facets `fac` loaded from `mesh` (viewfactors.facets.load_facets of the
    same `mesh`). A scene TOML (or a folder holding scene.toml): each facet's material is its
    face's in the mesh file (OBJ usemtl, glTF material; the [[mesh]] entry's `material` for
    PLY and STL), its values from [material.NAME], else its [[mesh]] entry, else `defaults`;
    [environment] temperature_K; [heat] length_unit_m. Any other mesh: its file's materials,
    every value from `defaults`. Bad values: SceneError naming the file, table and key."""
    from radiosity.formats.load import load_mesh

    path = os.path.abspath(os.fspath(mesh)) if isinstance(mesh, (str, os.PathLike)) else None
    if path and os.path.isdir(path) and os.path.exists(os.path.join(path, "scene.toml")):
        path = os.path.join(path, "scene.toml")
    opt = _defaults_dict(defaults)
    env = opt.pop("environment_K", None)
    unit = 1.0
    entries, overrides = [], {}
    n = len(fac)
    if path and path.lower().endswith(".toml"):
        from radiosity.scene.load import read_toml

        doc = read_toml(path)
        envt = _table(doc, "environment", ENVIRONMENT_KEYS, path)
        if "temperature_K" in envt:
            env = _check(f"{path}: [environment]", {"temperature_K": envt["temperature_K"]})[
                "temperature_K"]
        ht = _table(doc, "heat", HEAT_TABLE_KEYS, path)
        if "length_unit_m" in ht:
            unit = _check(f"{path}: [heat]", {"length_unit_m": ht["length_unit_m"]})[
                "length_unit_m"]
            if unit <= 0:
                raise SceneError(f"{path}: [heat] length_unit_m = {unit:g} must be positive")
        mats = doc.get("material", {})
        for name, t in mats.items():
            if not isinstance(t, dict):
                raise SceneError(f"{path}: [material.{name}] must be a table")
            overrides[name] = _check(f"{path}: [material.{name}]",
                                     {k: t[k] for k in HEAT_KEYS if k in t})
        for k, m in enumerate(doc.get("mesh", [])):
            entries.append((os.path.join(os.path.dirname(path), m["path"]),
                            m.get("material", "default"),
                            _check(f"{path}: [[mesh]] {k + 1}", {h: m[h] for h in HEAT_KEYS if h in m})))
        where = path
    else:
        entries = [(fn, "default", {}) if os.path.exists(fn) else (None, "default", {})
                   for fn in fac.sources]
        where = path or "the mesh"
    # each facet's material: its face's in its file
    names: list = []
    index: dict = {}
    material = np.zeros(n, np.int32)
    for k, (fn, default_mat, _) in enumerate(entries):
        sel = np.nonzero(fac.source == k)[0]
        if not len(sel):
            continue
        face_mat = load_mesh(fn, default_mat).face_material if fn else None
        for i in sel:
            name = face_mat[int(fac.face[i])] if face_mat is not None else default_mat
            if name not in index:
                index[name] = len(names)
                names.append(name)
            material[i] = index[name]
    # each (entry, material) pair's values
    e = np.zeros(n)
    fixed_t = np.zeros(n, bool)
    T = np.full(n, np.nan)
    q = np.zeros(n)
    for k, (_, _, mesh_vals) in enumerate(entries):
        for mi, name in enumerate(names):
            sel = (fac.source == k) & (material == mi)
            if not sel.any():
                continue
            ev, tv, qv = _resolve([overrides.get(name, {}), mesh_vals, opt], where, name)
            e[sel] = ev
            if tv is not None:
                fixed_t[sel] = True
                T[sel] = tv
            else:
                q[sel] = qv
    return HeatInputs(e, fixed_t, T, q, material, tuple(names), float(env or 0.0), unit)
