"""The parts catalogue (calibration/parts/*.toml): the shipped parts load, fit the shipped tunes, and a
bad file is refused naming the file and the field."""

from __future__ import annotations

import pytest

from dyno.errors import ConfigError
from dyno.tuning import actuators as act
from dyno.tuning.parts import apply_part, load_catalogue, match_parts
from dyno.tuning.tune import load_tune

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

CAT = "calibration/parts"


def test_shipped_catalogue_has_every_kind_with_sources_and_matches_the_shipped_tunes():
    parts = load_catalogue(CAT)
    kinds = {p.kind for p in parts}
    assert kinds == {"flyweights", "primary_spring", "secondary_spring", "helix"}
    assert all(p.source and 0 < p.tolerance_rel <= 0.5 and p.fits == "cvtech-ibc" for p in parts)
    stock = match_parts(load_tune("calibration/tunes/cvtech-stock.toml"), parts)
    assert {k: p.id for k, p in stock.items()} == {"flyweights": "fw-3x228g", "primary_spring": "ps-950n-18.2k",
                                                   "secondary_spring": "ss-140n@1", "helix": "hx-23deg"}
    heavy = match_parts(load_tune("calibration/tunes/heavy-flyweights.toml"), parts)
    assert heavy["flyweights"].id == "fw-3x262g"
    assert any(p.id.startswith("team-") for p in parts)  # the team's own parts, same format


def test_a_fitted_spring_is_the_spring_the_thesis_states():
    tune = load_tune("calibration/tunes/cvtech-stock.toml")
    spring = next(p for p in load_catalogue(CAT) if p.id == "ps-1020n-19k")
    t = apply_part(tune, spring)
    full = act.primary_full_travel_m(t)
    assert t.primary_spring.preload_n + t.primary_spring.rate_n_per_m * full == pytest.approx(1020.0)
    assert t.flyweights == tune.flyweights  # nothing else changed


@pytest.mark.parametrize("text, field", [
    ('schema = "dyno.parts/1"\nfits = "x"\n[[flyweights]]\nid = "a"\ncount = 3\nsource = "s"\n', "flyweights[0].mass_each_kg"),
    ('schema = "dyno.parts/1"\nfits = "x"\n[[helixes]]\nid = "h"\nangle_deg = 40\nangle_reference = "up"\n'
     'radius_m = 0.04\nsource = "s"\n', "helixes[0].angle_reference"),
    ('schema = "dyno.parts/1"\nfits = "x"\n[[primary_springs]]\nid = "p"\nrate_n_per_m = 1\nsource = "s"\n',
     "primary_springs[0].preload_n"),
    ('schema = "dyno.parts/1"\n[[secondary_springs]]\nid = "s"\npreload_n = 1\nrate_n_per_m = 1\nsource = "s"\n',
     "secondary_springs[0].fits"),
    ('schema = "dyno.parts/1"\nfits = "x"\n[[helixes]]\nid = "h"\nangle_deg = 40\nradius_mm = 40\nsource = "s"\n',
     "helixes[0].radius_mm"),
    ('schema = "dyno.parts/1"\nfits = "x"\n[[flyweights]]\nid = "a"\ncount = 3\nmass_each_kg = 0.2\n'
     'profile = "nope"\nsource = "s"\n', "flyweights[0].profile"),
])
def test_bad_catalogue_names_file_and_field(tmp_path, text, field):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ConfigError) as e:
        load_catalogue(tmp_path)
    assert e.value.field == field and e.value.path.endswith("bad.toml")
