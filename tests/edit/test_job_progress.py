"""The edit job's progress reports (``run_edit(on_stage=..., on_progress=...)``): every countable bar counts up to
its total, the deformer's hook is optional, and the reports change nothing in the result."""

import dataclasses
import json

import numpy as np

from deformers.arap import ArapConfig
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.edit import run_edit

BEND = {
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, -0.9]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.9], "max": [1, 1, 1.1]}}, "transform": {"translate": [0.3, 0, 0]}},
    ],
    "frames": 2,
}


class Recorder:
    """Listens as a display does: the stages started and each stage's reports ``(done, total, detail)``."""

    def __init__(self) -> None:
        self.stages: list[str] = []
        self.reports: dict[str, list[tuple]] = {}

    def on_stage(self, name: str) -> None:
        self.stages.append(name)

    def on_progress(self, stage: str, done, total, detail: str) -> None:
        assert stage == self.stages[-1], "a report of a stage that is not the current one"
        self.reports.setdefault(stage, []).append((done, total, detail))

    def bars(self, stage: str) -> list[list[tuple]]:
        """The stage's countable reports cut into bars: a bar is a run of reports of one total and one part (what
        leads a labelled detail, ``"a deform: …"``); uncountable reports end none."""
        bars, key = [], None
        for done, total, detail in self.reports.get(stage, []):
            if total is None:
                continue
            part = (total, detail.split(": ")[0] if ": " in detail else "")
            if part != key:
                bars.append([])
                key = part
            bars[-1].append((done, total, detail))
        return bars

    def check_bars(self, stage: str) -> list[list[tuple]]:
        """Assert every bar of ``stage`` counts monotonically from at least 0 up to its total, where it ends."""
        bars = self.bars(stage)
        for bar in bars:
            done = [d for d, _, _ in bar]
            assert done == sorted(done) and done[0] >= 0 and done[-1] == bar[-1][1], (stage, bar)
        return bars


def test_every_countable_stage_counts_up_to_its_total(capsule, tmp_path):
    capsule.save(tmp_path / "capsule.ply")
    (tmp_path / "edit.json").write_text(json.dumps(BEND))
    heard = Recorder()
    config = ArapConfig(max_iterations=30)
    result = run_edit(
        tmp_path / "capsule.ply",
        config,
        tmp_path / "edit.json",
        tmp_path / "out",
        cache_dir=tmp_path / "cache",  # cold: the proxy build's steps are told
        on_stage=heard.on_stage,
        on_progress=heard.on_progress,
    )
    assert heard.stages == ["load", "bind", "deform", "proxy", "lift", "write"]
    assert heard.reports["bind"] == [(0, None, "factorising")]

    (deform,) = heard.check_bars("deform")  # ARAP: max_iterations units per frame, one per iteration
    assert deform[0] == (0, 60, "frame 1/2 · iteration 0") and deform[-1][:2] == (60, 60)
    assert deform[-1][2].startswith("frame 2/2 · ") and deform[-1][2].endswith(" iterations")
    assert any(d.startswith("frame 2/2 · iteration 1 · ΔE/E ") for _, _, d in deform)  # frame 1: the rest

    steps = {d for _, total, d in heard.reports["proxy"] if total is None}
    assert {"cage (alpha wrap, decimation)", "tetwild", "embed", "margin"} <= steps

    (lift,) = heard.check_bars("lift")  # frames × (1 + refine rounds) × max_iterations
    assert lift[-1][1] == 2 * (1 + 3) * 100
    assert heard.reports["lift"][0] == (0, None, f"factorising ({result.report['proxy']['built_tets']} tets)")
    assert "write" not in heard.reports and "load" not in heard.reports


def test_reports_change_nothing(capsule, tmp_path, proxy_cache):
    """The same edit with and without a listener: the same deformed meshes (ARAP solves told each iteration)."""
    capsule.save(tmp_path / "capsule.ply")
    (tmp_path / "edit.json").write_text(json.dumps(BEND))
    args = (tmp_path / "capsule.ply", ArapConfig(), tmp_path / "edit.json")
    plain = run_edit(*args, tmp_path / "plain", cache_dir=proxy_cache, lift="knn3")
    heard = Recorder()
    told = run_edit(
        *args,
        tmp_path / "told",
        cache_dir=proxy_cache,
        lift="knn3",
        on_stage=heard.on_stage,
        on_progress=heard.on_progress,
    )
    for name in ("deformed_mesh_0000.ply", "deformed_mesh_0001.ply"):
        assert np.array_equal(SurfaceMesh.load(plain.out / name).vertices, SurfaceMesh.load(told.out / name).vertices)
    (lift,) = heard.check_bars("lift")  # knn3: one unit per frame, no refinement
    assert [d for d, _, _ in lift] == [0, 1, 1, 2, 2]


@dataclasses.dataclass
class ShiftConfig(DeformerConfig):
    """Moves the whole mesh (a third-party deformer that knows nothing of progress)."""

    _target: type = dataclasses.field(default_factory=lambda: Shift)


class Shift(Deformer):
    spec_keys = frozenset()

    def __init__(self, config: ShiftConfig) -> None:  # does not call Deformer.__init__
        self.config = config

    def bind(self, rest, edit):
        self.frames = rest.vertices[None] + [[0.1, 0.0, 0.0]] * np.linspace(0, 1, edit.frames)[:, None, None]

    def deform(self):
        return self.frames


def test_a_deformer_that_reports_nothing_runs_with_a_listener(capsule, tmp_path, proxy_cache):
    capsule.save(tmp_path / "capsule.ply")
    (tmp_path / "edit.json").write_text(json.dumps({"frames": 2}))
    heard = Recorder()
    result = run_edit(
        tmp_path / "capsule.ply",
        ShiftConfig(),
        tmp_path / "edit.json",
        tmp_path / "out",
        cache_dir=proxy_cache,
        on_stage=heard.on_stage,
        on_progress=heard.on_progress,
    )
    assert result.report["deformer"] == "Shift" and result.report["frames"] == 2
    assert "bind" not in heard.reports and "deform" not in heard.reports
    (lift,) = heard.check_bars("lift")
    assert lift[-1][1] == 2 * (1 + 3) * 100


def test_a_scene_edit_tells_each_instance_s_steps(capsule, tmp_path, proxy_cache):
    """Two capsules, the first edited: its bind, deform and lift are parts of the stage ``edit a``."""
    other = capsule.with_vertices(capsule.vertices + [2.0, 0.0, 0.0])
    n = capsule.n_vertices
    SurfaceMesh(
        np.concatenate([capsule.vertices, other.vertices]), np.concatenate([capsule.faces, other.faces + n])
    ).save(tmp_path / "scene.ply")
    edit = {k: v for k, v in BEND.items() if k != "frames"}
    spec = {"objects": [{"name": "a", "select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, 1.1]}}, "edit": edit}]}
    (tmp_path / "scene.json").write_text(json.dumps(spec))
    heard = Recorder()
    run_edit(
        tmp_path / "scene.ply",
        ArapConfig(max_iterations=20),
        tmp_path / "scene.json",
        tmp_path / "out",
        cache_dir=proxy_cache,
        on_stage=heard.on_stage,
        on_progress=heard.on_progress,
    )
    assert heard.stages == ["load", "proxy a", "edit a", "own a", "write"]
    assert heard.reports["edit a"][0] == (0, None, "a bind: factorising")
    deform, lift = heard.check_bars("edit a")
    assert deform[-1][:2] == (20, 20) and deform[-1][2].startswith("a deform: frame 1/1")
    assert lift[-1][1] == (1 + 3) * 100 and lift[0][2].startswith("a lift: frame 1/1")
