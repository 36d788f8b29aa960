"""The Python API example of docs/usage.md runs as printed (so the docs cannot drift from the API)."""

import os
import re
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def _python_block(doc: Path, heading: str) -> str:
    """The first ```python block after ``heading`` in ``doc``."""
    text = doc.read_text()
    start = text.index(heading)
    return re.search(r"```python\n(.*?)```", text[start:], re.S).group(1)


def test_usage_python_api_example_runs(tmp_path):
    code = _python_block(ROOT / "docs" / "usage.md", "## Python API")
    points = torch.zeros(5, 3)
    namespace = {"points_tensor": points}
    cwd = os.getcwd()
    os.chdir(tmp_path)  # the example writes its proxy cache beside it and reads configs/ from a checkout
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    try:
        exec(compile(code, "docs/usage.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    assert (tmp_path / "proxy-cache").is_dir()
    lift, deformed, field = namespace["lift"], namespace["deformed"], namespace["field"]
    assert deformed.shape == (len(namespace["frames"]), len(lift.proxy.vertices), 3)
    x_c = namespace["x_c"]
    assert x_c.points.shape == (5, 3) and x_c.jacobian.shape == (5, 3, 3)
    assert field.n_frames == len(namespace["frames"])
    # surface points of the edited frame map back near their rest positions (within the lift's residual, 2e-3)
    rest, frames = namespace["rest"], namespace["frames"]
    back = field.to_canonical(torch.as_tensor(frames[0][::50], dtype=torch.float32), frame=0)
    assert back.inside.all()
    err = (back.points.double() - torch.as_tensor(rest.vertices[::50])).norm(dim=1).max().item()
    assert err < 5e-3 * rest.bbox_diagonal
