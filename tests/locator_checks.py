"""Checks shared by the locator tests: two builds of the same grid agree."""

import torch

from nerfedit_plugin.bending.locate import TetLocator


def assert_primaries_tie(compiled: TetLocator, reference: TetLocator) -> None:
    """Where the octant primaries differ, both tets are listed in the cell and equally deep (1e-12) at the octant
    centre; and they differ in few octants."""
    a, b = compiled._octant_primary.long(), reference._octant_primary.long()
    differ = torch.nonzero(a != b).squeeze(1)
    assert len(differ) <= max(8, len(a) // 100), len(differ)
    if len(differ) == 0:
        return
    cell, octant = differ // 8, differ % 8
    padded = [n + 2 for n in reference.grid_shape]
    ijk = torch.stack([cell // (padded[1] * padded[2]), (cell // padded[2]) % padded[1], cell % padded[2]], 1) - 1
    h = 1 / reference._inv.to(torch.float64)
    bits = torch.stack([(octant >> 2) & 1, (octant >> 1) & 1, octant & 1], 1)
    centre = reference._lo.to(torch.float64) + (ijk + 0.25 + 0.5 * bits) * h
    table = reference._table
    depth = [table.exact_bary(t, centre[:, None])[:, 0].amin(1) for t in (a[differ], b[differ])]
    torch.testing.assert_close(depth[0], depth[1], atol=1e-12, rtol=0)
    for tets in (a[differ], b[differ]):
        listed = [
            int(t) in reference._entry_tet[s : s + n].tolist()
            for t, s, n in zip(tets, reference._cell_start[cell], reference._cell_count[cell])
        ]
        assert all(listed)
