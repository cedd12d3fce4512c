"""Every registered transport method is a full `TransportMethod` (methods/base.py): each member
the protocol declares is there, with a signature its callers can use, and what the registry
derives from the methods (the run store's groups, the all-pairs method) holds together."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from radiosity.methods.base import (METHODS, Refinement, TransportMethod, all_pairs_method,
                                    get_method, store_groups)

#: what callers outside methods/ use of a method (besides name, section, store_groups, all_pairs
#: and refinement)
DECLARED = {"check", "check_scene", "plan_lines", "build", "built", "require", "open",
            "gathers", "finish", "radiance_at", "open_views", "kept", "summary_row"}
P = inspect.Parameter
POSITIONAL = (P.POSITIONAL_ONLY, P.POSITIONAL_OR_KEYWORD)


def incompatible(declared, impl) -> list[str]:
    """How `impl` fails to take every call `declared` allows: the declared positional
    parameters by the same names in the same order, every declared keyword, nothing more
    that is required, and **options where the declaration has them."""
    d, i = inspect.signature(declared).parameters, inspect.signature(impl).parameters
    var_kw = any(p.kind == P.VAR_KEYWORD for p in i.values())
    var_pos = any(p.kind == P.VAR_POSITIONAL for p in i.values())
    dpos = [p for p in d.values() if p.kind in POSITIONAL]
    ipos = [p for p in i.values() if p.kind in POSITIONAL]
    out = []
    for k, p in enumerate(dpos):
        if k >= len(ipos):
            if not var_pos:
                out.append(f"no positional {p.name!r}")
        elif ipos[k].name != p.name:
            out.append(f"positional {k} is {ipos[k].name!r}, declared {p.name!r}")
        elif ipos[k].default is P.empty and p.default is not P.empty:
            out.append(f"{p.name!r} has no default")
    out += [f"{q.name!r} is required, not declared" for q in ipos[len(dpos):]
            if q.default is P.empty]
    for p in d.values():
        if p.kind == P.KEYWORD_ONLY:
            q = i.get(p.name)
            if q is None and not var_kw:
                out.append(f"no keyword {p.name!r}")
            elif q is not None and q.default is P.empty and p.default is not P.empty:
                out.append(f"keyword {p.name!r} has no default")
        if p.kind == P.VAR_KEYWORD and not var_kw:
            out.append("no **options")
    out += [f"keyword {q.name!r} is required, not declared" for q in i.values()
            if q.kind == P.KEYWORD_ONLY and q.default is P.empty and q.name not in d]
    return out


def members(cls) -> list[str]:
    """The methods `cls` declares abstract (what every implementation must provide)."""
    return sorted(cls.__abstractmethods__)


@pytest.mark.parametrize("name", sorted(METHODS))
def test_every_registered_method_provides_the_protocol(name):
    m = get_method(name)
    assert isinstance(m, TransportMethod), f"{name}: {type(m).__name__} is no TransportMethod"
    assert m.name == name and isinstance(m.section, str) and m.section
    assert isinstance(m.all_pairs, bool)
    assert isinstance(m.store_groups, tuple) and m.store_groups
    assert all(isinstance(g, str) for g in m.store_groups)
    assert m.refinement is None or isinstance(m.refinement, Refinement)
    assert members(TransportMethod) == sorted(DECLARED)
    bad = {k: incompatible(getattr(TransportMethod, k), getattr(type(m), k))
           for k in members(TransportMethod)}
    if m.refinement is not None:
        bad.update({f"refinement.{k}": incompatible(getattr(Refinement, k),
                                                    getattr(type(m.refinement), k))
                    for k in members(Refinement)})
    bad = {k: v for k, v in bad.items() if v}
    assert not bad, f"{name}: {bad}"


def test_the_check_finds_a_missing_member_and_a_wrong_signature():
    """The checks above can fail: an implementation without a declared member cannot be made,
    and one whose signature drops or renames what callers pass is reported."""
    class Partial(TransportMethod):
        def built(self, rs):
            return False

    with pytest.raises(TypeError, match="abstract"):
        Partial()

    def finish(self, opened, L, settings):
        return {}, {}

    def build(self, run_dir, client, settings, *, resume=False):
        return None

    def open_(self, rs, client, settings, where):
        return None

    assert incompatible(TransportMethod.finish, finish) == [
        "positional 3 is 'settings', declared 'rows'", "no positional 'settings'"]
    assert incompatible(TransportMethod.build, build) == [
        "no keyword 'progress'", "no keyword 'occlusion'", "no keyword 'unit'",
        "no keyword 'on_done'"]
    assert incompatible(TransportMethod.open, open_) == [
        "'where' is required, not declared", "no **options"]
    assert incompatible(TransportMethod.open, type(get_method("hierarchical")).open) == []


def test_store_groups_come_from_the_registry_and_drop_as_one_stage(tmp_path):
    """The run store knows the methods' groups from the registry (no method named in
    runtime/store.py): a method's stage re-run (drop_after the raster) deletes every method's
    groups and the solution; a solve (drop_after a method's group) deletes only the solution."""
    from radiosity.runtime.store import AFTER_METHOD, BEFORE_METHOD, RunStore, stages

    groups = store_groups()
    assert len(set(groups)) == len(groups), "two methods claim one store group"
    assert not set(groups) & set(BEFORE_METHOD + AFTER_METHOD)
    assert set(groups) == {g for name in METHODS for g in get_method(name).store_groups}
    assert stages()[len(BEFORE_METHOD)] == groups
    rs = RunStore(str(tmp_path / "run"), "w")
    every = BEFORE_METHOD + groups + AFTER_METHOD
    one = {"a": np.zeros(2)}
    for g in every:
        rs.write_arrays(g, one)
    rs.drop_after(groups[-1])
    assert [g for g in every if rs.has(g)] == list(BEFORE_METHOD + groups)
    rs.drop_after("raster")
    assert [g for g in every if rs.has(g)] == list(BEFORE_METHOD)
    with pytest.raises(Exception, match="no group of the run store"):
        rs.drop_after("nonsense")


def test_one_method_takes_every_pair():
    """The preview and the accuracy study's kernels need the method without refinement."""
    m = all_pairs_method()
    assert m.all_pairs and m.refinement is None and not m.gathers(None)
