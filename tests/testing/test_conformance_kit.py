"""The conformance kit passes a correct deformer and fails each deliberately broken one on the right property;
parametrize_with_checks makes one named pytest case per property."""

import dataclasses
import inspect
import math
import re
import textwrap

import numpy as np
import pytest
import tyro
from scipy.spatial.transform import Rotation

import nerfedit_plugin
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.mesh_field import MeshFieldConfig
from nerfedit_plugin.testing import (
    CHECKS,
    FIELD_CHECKS,
    check_config,
    check_deformer,
    check_identity,
    check_malformed,
    default_edit,
    default_mesh,
    deformer_checks,
    field_checks,
    malformed_edits,
    parametrize_with_checks,
    rigid_fit,
)
from nerfedit_plugin.testing import fields as field_kit

pytest_plugins = ["pytester"]


class FollowDeformer(Deformer):
    """A correct (if dull) deformer: the whole mesh follows the last handle's transform."""

    def bind(self, rest, edit):
        self.rest = rest.vertices.copy()
        idx, _ = edit.handle_targets(rest.vertices)  # validates selections against the mesh
        moving = [h for h in edit.handles if h.transform is not None]
        self.handle = moving[-1] if moving else None
        self.pivot = (
            rest.vertices[self.handle.selection.indices(rest.vertices, edit.source)].mean(0) if moving else None
        )
        self.times = edit.times

    def deform_points(self, points, frame):
        points = np.asarray(points, dtype=np.float64)
        return (
            points.copy() if self.handle is None else self.handle.transform.apply(points, self.times[frame], self.pivot)
        )

    def deform(self):
        return np.stack([self.deform_points(self.rest, f) for f in range(len(self.times))])


@dataclasses.dataclass
class FollowConfig(DeformerConfig):
    """Config of the reference deformer."""

    _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: FollowDeformer)
    strength: float = 1.0
    """Unused knob, documented as every field must be."""


def config_of(deformer: type) -> DeformerConfig:
    @dataclasses.dataclass
    class Config(DeformerConfig):
        _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: deformer)

    return Config()


# ---- deliberately broken deformers (each breaks one property) ----------------------------------------------------
class WrongShape(FollowDeformer):
    def deform(self):
        return super().deform()[-1]


class Float32(FollowDeformer):
    def deform(self):
        return super().deform().astype(np.float32)


class NonFinite(FollowDeformer):
    def deform(self):
        out = super().deform()
        out[-1, 0, 0] = np.nan
        return out


class Mutating(FollowDeformer):
    def bind(self, rest, edit):
        super().bind(rest, edit)
        rest.vertices *= 1.0 + 1e-9


class Frozen(FollowDeformer):
    def deform(self):
        return np.repeat(self.rest[None], len(self.times), axis=0)


class Noisy(FollowDeformer):
    def deform(self):
        return super().deform() + 1e-9 * np.random.default_rng().normal(size=(len(self.times), len(self.rest), 3))


class IgnoresIdentity(FollowDeformer):
    def deform_points(self, points, frame):
        return super().deform_points(points, frame) + [0.01, 0.0, 0.0]


class Shearing(FollowDeformer):
    """Adds a shear proportional to the handle's translation: invisible under the identity edit, not rigid."""

    def deform_points(self, points, frame):
        out = super().deform_points(points, frame)
        if self.handle is not None:
            out[:, 0] += self.times[frame] * np.linalg.norm(self.handle.transform.translate) * points[:, 2]
        return out


class Reversed(FollowDeformer):
    def deform(self):
        return super().deform()[:, ::-1].copy()


class Lenient(FollowDeformer):
    """Accepts an extra top-level key and never validates it."""

    spec_keys = frozenset({"handles", "amount"})

    @classmethod
    def placed_edit(cls, edit, scale, offset, base_dir, folder):
        return edit  # amount is never read


class WrongError(Lenient):
    def bind(self, rest, edit):
        super().bind(rest, edit)
        if not math.isfinite(edit.extra.get("amount", 0.0)):
            raise ValueError("amount is NaN")


class BadPoints(FollowDeformer):
    """deform() is right, deform_points() is off by 1e-3."""

    def deform_points(self, points, frame):
        return super().deform_points(points, frame) + 1e-3

    def deform(self):
        return np.stack([FollowDeformer.deform_points(self, self.rest, f) for f in range(len(self.times))])


class Snapping(FollowDeformer):
    """Rounds its output to an absolute grid of 1e-6: unseen on a mesh 2 units across, wrong on one 3e-4 across."""

    def deform(self):
        return np.round(super().deform(), 6)


class Float32Sums(FollowDeformer):
    """Adds its displacements in float32: unseen near the origin, wrong 1e5 diagonals away."""

    def deform(self):
        out = super().deform()
        return (self.rest.astype(np.float32) + (out - self.rest).astype(np.float32)).astype(np.float64)


BROKEN = [
    (WrongShape, "output", r"returned shape \(162, 3\), expected \(2, 162, 3\)"),
    (Float32, "output", r"dtype float32, expected float64"),
    (NonFinite, "output", r"1 non-finite values"),
    (Mutating, "output", r"modified the rest mesh in place"),
    (Frozen, "output", r"the edit moved nothing"),
    (Noisy, "deterministic", r"two binds of the same edit differ"),
    (IgnoresIdentity, "identity", r"identity edit moved vertices by up to 0.01"),
    (Shearing, "rigid", r"not a rigid motion of the rest mesh"),
    (Reversed, "vertex_order", r"is the vertex order preserved"),
    (Lenient, "malformed", r"NaN at amount: accepted"),
    (WrongError, "malformed", r"NaN at amount: raised ValueError\('amount is NaN'\), expected NerfEditError"),
    (BadPoints, "points", r"deform_points\(rest\) differs from deform\(\)"),
    (Snapping, "placement", r"identity edit moved vertices .* \[rest mesh scaled by 2\^-13\]"),
    (Float32Sums, "placement", r"identity edit moved vertices .* \[rest mesh moved 1e5 diagonals away\]"),
]


def test_reference_deformer_passes_every_check():
    check_deformer(FollowConfig())
    check_deformer(FollowConfig(), edit={**default_edit(default_mesh()), "frames": 4})


@pytest.mark.parametrize("deformer, check, message", BROKEN, ids=[b[0].__name__ for b in BROKEN])
def test_each_broken_deformer_fails_its_check(deformer, check, message):
    config = config_of(deformer)
    edit = {**default_edit(default_mesh()), "amount": 1.0} if issubclass(deformer, Lenient) else None
    with pytest.raises(AssertionError, match=message):
        CHECKS[check](config, edit=edit)
    with pytest.raises(AssertionError):
        check_deformer(config, edit=edit, skip=("config",))


def test_config_checks():
    check_config(FollowConfig())

    @dataclasses.dataclass
    class Undocumented(FollowConfig):
        """Has a field without a docstring."""

        iterations: int = 3

    @dataclasses.dataclass
    class NotADeformer(DeformerConfig):
        """Targets something that is not a Deformer."""

        _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: dict)

    @dataclasses.dataclass
    class NotYaml(FollowConfig):
        """Holds a value YAML cannot represent."""

        tags: frozenset = frozenset({"a"})
        """A set."""

    with pytest.raises(AssertionError, match=r"fields without a docstring .*\['iterations'\]"):
        check_config(Undocumented())
    with pytest.raises(AssertionError, match=r"_target is <class 'dict'>, not a Deformer subclass"):
        check_config(NotADeformer())
    with pytest.raises(AssertionError, match=r"not YAML-safe"):
        check_config(NotYaml())


class NoHooks(Deformer):
    """A spec-less-handles plugin: ``{"amount": a}`` moves everything by a·t along x; the base's kit hooks (None)."""

    spec_keys = frozenset({"amount"})

    def bind(self, rest, edit):
        amount = edit.extra.get("amount")
        if isinstance(amount, bool) or not isinstance(amount, (int, float)) or not math.isfinite(amount):
            raise NerfEditError(f"{edit.source}: amount: expected a finite number, got {amount!r}")
        self.rest, self.amount, self.times = rest.vertices.copy(), amount, edit.times

    def deform(self):
        return np.stack([self.rest + [t * self.amount, 0.0, 0.0] for t in self.times])

    @classmethod
    def placed_edit(cls, edit, scale, offset, base_dir, folder):
        return {**edit, "amount": scale * edit["amount"]}


class Shift(NoHooks):
    """The same plugin with ``identity_edit`` / ``rigid_edit`` hooks giving its variants."""

    @classmethod
    def identity_edit(cls, edit, rest):
        return {**edit, "amount": 0.0}

    @classmethod
    def rigid_edit(cls, edit, rest):
        return {**edit, "amount": 0.2 * rest.bbox_diagonal}


def test_hooks_and_explicit_variants_for_plugins_without_handles():
    edit = {"amount": 0.2, "frames": 2}
    check_deformer(config_of(Shift), edit=edit, skip=("config",))  # identity/rigid through the hooks
    with pytest.raises(ValueError, match=r"pass identity_edit= or skip=\('identity',\)"):
        check_identity(config_of(NoHooks), edit=edit)
    check_deformer(
        config_of(NoHooks), edit=edit, identity_edit={"amount": 0}, rigid_edit={"amount": 1.0}, skip=("config",)
    )
    with pytest.raises(AssertionError, match=r"identity edit moved"):  # an explicit dict is used as given
        check_identity(config_of(NoHooks), edit=edit, identity_edit={"amount": 0.1})
    with pytest.raises(ValueError, match=r"has no 'handles' key"):
        check_identity(config_of(NoHooks))


def test_caller_bad_edits_are_checked():
    edit = {"amount": 0.2}
    check_malformed(config_of(Shift), edit=edit, bad_edits=[{"amount": "far"}])
    with pytest.raises(AssertionError, match=r"bad_edits\[0\]: accepted"):
        check_malformed(config_of(Shift), edit=edit, bad_edits=[{"amount": 3}])


def test_malformed_variants(tmp_path):
    rest = default_mesh()
    edit = default_edit(rest)
    cases = dict(malformed_edits(edit, rest, {"handles"}))
    assert {"unknown top-level key", "out-of-range handle index 1000000000", "out-of-range handle index -1"} <= set(
        cases
    )
    nans = [c for c in cases if c.startswith("NaN at ")]
    assert len(nans) == 3 and all(math.isnan(_leaf(cases[c], c[len("NaN at ") :])) for c in nans)
    (tmp_path / "file.ply").write_text("")
    with_file = dict(malformed_edits({"handles": edit["handles"], "mesh": "file.ply"}, rest, {"handles"}, tmp_path))
    assert with_file["missing file for 'mesh'"]["mesh"] == "nerfedit-kit-missing-file.ply"


def _leaf(obj, dotted):
    for key in dotted.split("."):
        obj = obj[int(key)] if isinstance(obj, list) else obj[key]
    return obj


def test_skip_names_are_validated():
    with pytest.raises(ValueError, match=r"unknown checks in skip: \['speed'\]"):
        check_deformer(FollowConfig(), skip=("speed",))


def test_rigid_fit():
    points = np.random.default_rng(0).normal(size=(50, 3))
    rotation = Rotation.from_rotvec([0.3, -1.0, 0.4]).as_matrix()
    r, t, residual = rigid_fit(points, points @ rotation.T + [1.0, 2.0, 3.0])
    assert np.allclose(r, rotation) and np.allclose(t, [1, 2, 3]) and residual < 1e-12
    assert rigid_fit(points, 1.1 * points)[2] > 0.05
    assert rigid_fit(points, -points)[2] > 0.1  # a reflection is not a rotation


# ---- one case per property: deformer_checks / field_checks / parametrize_with_checks --------------------------------
@parametrize_with_checks([FollowConfig(), FollowConfig(strength=2.0)])
def test_reference_deformer_case_by_case(check):
    check()


def _ids(mark) -> list[str]:
    assert mark.mark.args[0] == "check" and len(mark.mark.args[1]) == len(mark.mark.kwargs["ids"])
    return mark.mark.kwargs["ids"]


def test_one_case_per_check_with_readable_ids():
    assert _ids(parametrize_with_checks(FollowConfig())) == [f"FollowConfig-{name}" for name in CHECKS]
    several = _ids(parametrize_with_checks([FollowConfig(), FollowConfig(strength=2.0)], skip=("rigid", "points")))
    kept = [name for name in CHECKS if name not in ("rigid", "points")]
    assert several == [f"FollowConfig-{n}" for n in kept] + [f"FollowConfig(strength=2.0)-{n}" for n in kept]
    assert _ids(parametrize_with_checks(MeshFieldConfig())) == [f"MeshFieldConfig-{name}" for name in FIELD_CHECKS]
    assert [name for name, _ in deformer_checks(FollowConfig(), skip=("config",))] == list(CHECKS)[1:]
    assert [name for name, _ in field_checks(MeshFieldConfig(), skip=("extract",))] == list(FIELD_CHECKS)[:-1]


def test_usage_errors_at_collection():
    with pytest.raises(ValueError, match=r"unknown checks in skip: \['speed'\]"):
        parametrize_with_checks(FollowConfig(), skip=("speed",))
    with pytest.raises(ValueError, match=r"unknown checks in skip: \['rigid'\]"):  # a deformer check, not a field one
        parametrize_with_checks(MeshFieldConfig(), skip=("rigid",))
    with pytest.raises(TypeError, match=r"expected a DeformerConfig or FieldConfig instance"):
        parametrize_with_checks(FollowConfig)  # the class, not an instance
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'edit'"):
        parametrize_with_checks(MeshFieldConfig(), edit={})


def test_public_api_names():
    assert nerfedit_plugin.parametrize_with_checks is parametrize_with_checks
    assert nerfedit_plugin.check_deformer is check_deformer and nerfedit_plugin.check_field is field_kit.check_field


EXACT = [
    b
    for b in BROKEN
    if b[0] in (Noisy, IgnoresIdentity, Shearing, Lenient, WrongError, BadPoints, Snapping, Float32Sums)
]
#: checks whose failure the placement check repeats (it runs identity and rigid on the placed mesh)
REPEATED = {"identity", "rigid", "deterministic"}


@pytest.mark.parametrize("deformer, check, message", EXACT, ids=[b[0].__name__ for b in EXACT])
def test_broken_deformer_fails_exactly_its_case(deformer, check, message):
    edit = {**default_edit(default_mesh()), "amount": 1.0} if issubclass(deformer, Lenient) else None
    failed = {}
    for name, run in deformer_checks(config_of(deformer), edit=edit):
        try:
            run()
        except AssertionError as exc:
            failed[name] = str(exc)
    assert list(failed) == [check] + (["placement"] if check in REPEATED else []), failed
    assert re.search(message, failed[check])


def test_call_keywords_override_the_bound_ones(monkeypatch, tmp_path):
    seen = []
    monkeypatch.setitem(CHECKS, "malformed", lambda config, rest, edit, **kw: seen.append((rest, edit, kw)))
    check = dict(deformer_checks(FollowConfig(), edit={"frames": 1}, bad_edits=[{"a": 1}]))["malformed"]
    check()
    check(base_dir=tmp_path, bad_edits=())
    assert seen == [
        (None, {"frames": 1}, {"base_dir": None, "bad_edits": [{"a": 1}]}),
        (None, {"frames": 1}, {"base_dir": tmp_path, "bad_edits": []}),
    ]


def test_field_checks_share_one_lazily_built_field(monkeypatch):
    built, ran = [], []
    monkeypatch.setattr(field_kit, "build_field", lambda config: built.append(config) or "field")
    for name in FIELD_CHECKS:
        monkeypatch.setitem(field_kit.CHECKS, name, lambda arg, name=name: ran.append((name, arg)))
    config = MeshFieldConfig()
    mark = parametrize_with_checks([config, config])
    assert built == []  # nothing is built at collection
    for check in mark.mark.args[1]:
        check()
    assert built == [config, config]  # once per config, not per check
    assert ran == 2 * ([("config", config)] + [(name, "field") for name in list(FIELD_CHECKS)[1:]])


def test_pytest_reports_the_failing_property_by_name(pytester):
    """A plugin's test module run by pytest: the broken property is one failing case named after it, the others
    pass, skipped properties have no case."""
    config = textwrap.dedent('''
        @dataclasses.dataclass
        class BrokenConfig(DeformerConfig):
            """Ignores the identity edit."""

            _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: IgnoresIdentity)


        @parametrize_with_checks(BrokenConfig(), skip=("rigid",))
        def test_conformance(check):
            check()
    ''')
    pytester.makepyfile(
        test_plugin="\n".join(
            [
                "import dataclasses",
                "import numpy as np",
                "import tyro",
                "from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig",
                "from nerfedit_plugin.testing import parametrize_with_checks",
                "",
                inspect.getsource(FollowDeformer),
                inspect.getsource(IgnoresIdentity),
                config,
            ]
        )
    )
    result = pytester.runpytest("-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=len(CHECKS) - 3, failed=2)  # identity, and placement repeating it
    result.stdout.fnmatch_lines(
        [
            "*_ test_conformance[[]BrokenConfig-identity[]] _*",
            "E * BrokenConfig: identity edit moved vertices by up to 0.01 *",
            "FAILED test_plugin.py::test_conformance[[]BrokenConfig-identity[]]*",
        ]
    )
    assert "BrokenConfig-rigid" not in result.stdout.str()
