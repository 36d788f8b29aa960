"""bench/bench_paper.py end to end in its tiny variant (the exact mesh field: no training error), and its docs block."""

import bench_paper
import numpy as np
import pytest


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return bench_paper.run(tmp_path_factory.mktemp("bench-paper") / "work", bench_paper.TINY, log=lambda _: None)


def test_ours_ranks_best_with_the_exact_field(tiny):
    metrics = tiny["metrics"]
    assert set(metrics) == set(bench_paper.METHODS) - {"nerf-mesh"}  # the tiny variant trains no nerf
    ours = metrics["tet-arap"]
    for other in ("closest-point-per-sample", "knn3-per-sample", "closest-point", "knn3", "tet-edit"):
        assert ours["psnr"] > metrics[other]["psnr"] + 1.0, other
        assert ours["ssim"] > metrics[other]["ssim"], other
    assert ours["psnr"] > 30.0 and np.isfinite(ours["psnr"])  # bent, so not the rest images
    assert metrics["no-view-dirs"] == ours  # the mesh field's colour does not depend on the view
    assert tiny["lift"]["tet-arap"]["inverted_tets"] == 0
    for method in ("closest-point", "knn3"):  # the paper's: each sample bent by the posed mesh itself, no proxy
        assert f"{method}-per-sample" not in tiny["lift"] and metrics[f"{method}-per-sample"] != metrics[method]


def test_tables_name_every_row_and_the_targets(tiny):
    text = bench_paper.tables(tiny, bench_paper.TINY)
    for key, (_, label, *_) in bench_paper.METHODS.items():
        assert (label in text) == (key in tiny["metrics"]), label
    assert "Targets:" in text and "ours ≥ 30 dB: **met**" in text
    assert text.count("| — (no proxy) | — |") == 2  # the per-sample rows
    ours, metrics = tiny["metrics"]["tet-arap"]["psnr"], tiny["metrics"]
    paper = max(metrics[k]["psnr"] for k in ("closest-point-per-sample", "knn3-per-sample"))
    carried = max(metrics[k]["psnr"] for k in ("closest-point", "knn3"))
    assert f"the paper's best baseline (per sample) + 3 dB ({ours - paper:+.2f} dB)" in text
    assert f"carried by our proxy (at the proxy vertices; not a target): {ours - carried:+.2f} dB." in text


def test_docs_block_is_replaced_between_the_markers_only(tmp_path):
    doc = tmp_path / "benchmarks.md"
    before, after = "# Benchmarks\n\ntext before\n\n", "\n\n## Notes\n\ntext after\n"
    doc.write_text(f"{before}{bench_paper.BEGIN}\nold tables\n{bench_paper.END}{after}")
    bench_paper.write_docs("| new | table |", "python bench/bench_paper.py", doc)
    bench_paper.write_docs("| newer | table |", "python bench/bench_paper.py", doc)
    text = doc.read_text()
    assert text.startswith(before + bench_paper.BEGIN) and text.endswith(bench_paper.END + after)
    assert "| newer | table |" in text and "new |" not in text.replace("newer", "") and "old" not in text
    assert "`python bench/bench_paper.py`, 20" in text  # command and date
