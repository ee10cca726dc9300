"""The real procedural sofa: every sample segments the same way and matches the template consistently."""

import pytest

from proctex.parts import analyse, match_groups
from proctex.sources import FolderSource

from .test_parts import SOFA_GROUPS


@pytest.fixture(scope="module")
def sofa(sofa_dir):
    src = FolderSource(sofa_dir)
    ti = src.template_index()
    template = src.load(ti)
    return src, ti, template, analyse(template)


def test_folder_layout_and_template(sofa):
    src, ti, template, tg = sofa
    assert len(src.indices("train")) == 50 and len(src.indices("test")) == 50
    assert src.samples[ti].split == "train"
    assert src.space.names == ["Depth", "Width", "Back/Side height", "Cushion thickness"]
    assert [g.members for g in tg.groups] == SOFA_GROUPS


@pytest.mark.slow
def test_every_sofa_sample_matches_the_template_consistently(sofa):
    src, ti, template, tg = sofa
    assignments = set()
    for i in range(len(src)):
        shape = src.load(i)
        g = analyse(shape)
        assert [grp.members for grp in g.groups] == SOFA_GROUPS, src.samples[i].id
        m = match_groups(shape, g, template, tg)
        assert not m.added and not m.missing, src.samples[i].id
        # Every sample has the same parts in the same order (armrests 0-1, base 2, back cushion 5,
        # seat cushion 6, flat parts 3, 4, 7, 8), so one consistent assignment maps each group to the
        # template group holding the same parts.
        assignments.add(tuple(tg.groups[b].members[0] for a, b in sorted(m.pairs)))
        assert max(m.cost[a, b] for a, b in m.pairs) < m.threshold
    assert assignments == {tuple(members[0] for members in SOFA_GROUPS)}
