"""Sweeps without running anything: `--set` overrides, the sweep file, the design expansion (grid,
random, lhs; seeds; ranges, log, integers), run keys, bad input, and the report's statistics."""

import math
import os
import textwrap

import numpy as np
import pytest

from tests.conftest import ROOT
from vrsim.common import ScenarioError
from vrsim.services.sim import overrides, scenario
from vrsim.services.sim.sweep import (
    configurations,
    load_sweep,
    mean_ci95,
    pareto_front,
    parse_sweep,
    plan,
    variant_groups,
)
from vrsim.services.sim.sweep.design import _scenario_key

BASE = """
name = "base"
seed = 7
[field]
rectangle = { width_m = 72.0, length_m = 150.0, lat = 52.0, lon = 10.0 }
[map]
synthetic = "uniform"
[controller]
gains = "manual"
kp = 0.5
ki = 2.0
"""


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    return tmp_path


def sweep_of(folder, body: str):
    path = folder / "s.toml"
    path.write_text(textwrap.dedent(body))
    return load_sweep(str(path))


# --- --set -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, value", [
    ("0.8", 0.8), ("12", 12), ("true", True), ('"dgps"', "dgps"), ("dgps", "dgps"), ("[1, 2]", [1, 2]),
    ("{ mean_kg_ha = 150.0 }", {"mean_kg_ha": 150.0}), ("my run", "my run"),
])
def test_set_values_are_toml_values_or_else_strings(text, value):
    assert overrides._parse_value(text) == value
    assert type(overrides._parse_value(text)) is type(value)


def test_set_reaches_top_level_tables_and_nested_tables(folder):
    sc = scenario.load(str(folder / "base.toml"), [
        overrides.parse_assignment("controller.kp=0.8"), overrides.parse_assignment("implement.sections=12"),
        overrides.parse_assignment("gnss.kind=dgps"), overrides.parse_assignment("seed=3"),
        overrides.parse_assignment("map.params.rate_kg_ha=150.0"),
    ])
    assert (sc.controller.kp, sc.implement.sections, sc.gnss.kind, sc.seed) == (0.8, 12, "dgps", 3)
    assert sc.map.params == {"rate_kg_ha": 150.0}


def edited(text: str, key: str, value: str) -> str:
    """`text` with ``key = value`` written into it (replacing the key if there), as a user would."""
    *tables, name = key.split(".")
    section = ".".join(tables)
    lines, current, done = text.splitlines(), "", False
    for i, line in enumerate(lines):
        if line.startswith("["):
            if current == section and not done:  # the section ends without the key: add it
                lines.insert(i, f"{name} = {value}")
                done = True
                break
            current = line.strip("[]")
        elif current == section and line.split("=")[0].strip() == name:
            lines[i], done = f"{name} = {value}", True
            break
    if not done and section and current == section:
        lines.append(f"{name} = {value}")
    elif not done:
        lines = [f"{name} = {value}", *lines] if not section else \
            [*lines, f"[{section}]", f"{name} = {value}"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("key, value", [
    ("implement.width_m", "-3.0"), ("controller.kpp", "1"), ("controller.kp", '"abc"'),
    ("gnss.kind", '"galileo"'), ("implement.sections", "4.5"), ("seed", "-1"), ("tractorr.x", "1"),
])
def test_set_is_checked_exactly_like_the_file(folder, key, value):
    """The same bad value, once by --set and once written in the file: the same message."""
    path = str(folder / "base.toml")
    with pytest.raises(ScenarioError) as by_set:
        scenario.load(path, [overrides.parse_assignment(f"{key}={value}")])
    with pytest.raises(ScenarioError) as in_file:
        scenario.parse(edited(BASE.replace("seed = 7\n", ""), key, value), source=path, base_dir=str(folder))
    assert str(by_set.value) == str(in_file.value)
    assert str(by_set.value).startswith(path + ": ")


@pytest.mark.parametrize("text, message", [
    ("kp", "expected KEY=VALUE"), ("=1", "not a dotted key"), ("controller..kp=1", "not a dotted key"),
])
def test_bad_assignments_are_named(text, message):
    with pytest.raises(ScenarioError, match=message):
        overrides.parse_assignment(text)


def test_set_through_a_value_that_is_not_a_table(folder):
    with pytest.raises(ScenarioError, match=r"base.toml: cannot set controller.kp.x: controller.kp is 0.5"):
        scenario.load(str(folder / "base.toml"), [("controller.kp.x", 1)])


# --- the design --------------------------------------------------------------------------------------

def test_grid_is_every_combination_times_seeds_times_scenarios(folder):
    sw = sweep_of(folder, """
        scenarios = ["base.toml", "default"]
        seeds = [1, 2, 3]
        [axes]
        "controller.gains" = ["manual"]        # the default's gains are the paper's
        "controller.kp" = [0.4, 0.6, 0.8]
        "implement.delivery_delay_s" = { min = 0.4, max = 1.6, n = 4 }
        "gnss.kind" = ["rtk", "dgps"]
    """)
    specs = plan(sw)
    assert len(specs) == 2 * 3 * 3 * 4 * 2
    assert len({s.key for s in specs}) == len(specs)
    delays = sorted({dict(s.axes)["implement.delivery_delay_s"] for s in specs})
    assert delays == pytest.approx([0.4, 0.8, 1.2, 1.6])
    one = next(s for s in specs if s.scenario == "default" and s.seed == 2
               and dict(s.axes) == {"controller.gains": "manual", "controller.kp": 0.6,
                                    "implement.delivery_delay_s": delays[1], "gnss.kind": "dgps"})
    sc = one.load()
    assert (sc.controller.kp, sc.gnss.kind, sc.seed, sc.name) == (0.6, "dgps", 2, "default")


def test_axes_as_nested_tables_mean_the_same(folder):
    quoted = sweep_of(folder, """
        scenarios = ["base.toml"]
        [axes]
        "controller.kp" = [0.4, 0.8]
        "implement.delivery_delay_s" = { min = 0.4, max = 1.6, n = 2 }
    """)
    nested = sweep_of(folder, """
        scenarios = ["base.toml"]
        [axes.controller]
        kp = [0.4, 0.8]
        [axes.implement]
        delivery_delay_s = { min = 0.4, max = 1.6, n = 2 }
    """)
    assert quoted.axes == nested.axes
    assert [s.key for s in plan(quoted)] == [s.key for s in plan(nested)]


def test_without_seeds_each_scenario_keeps_its_own(folder):
    specs = plan(sweep_of(folder, 'scenarios = ["base.toml"]\n[axes]\n"controller.kp" = [0.4]\n'))
    assert [s.seed for s in specs] == [7]


def test_no_axes_grid_is_one_run_per_seed(folder):
    specs = plan(sweep_of(folder, 'scenarios = ["base.toml"]\nseeds = [1, 2]\n'))
    assert sorted(s.seed for s in specs) == [1, 2] and all(s.axes == () for s in specs)


def test_log_and_integer_ranges(folder):
    sw = sweep_of(folder, """
        scenarios = ["base.toml"]
        [axes]
        "controller.ki" = { min = 0.1, max = 10.0, n = 3, log = true }
        "implement.sections" = { min = 2, max = 8, n = 4 }
    """)
    ki, sections = sw.axes
    assert ki.values == pytest.approx((0.1, 1.0, 10.0))
    assert sections.values == (2, 4, 6, 8) and all(type(v) is int for v in sections.values)
    assert len(plan(sw)) == 12


@pytest.mark.parametrize("design", ["random", "lhs"])
def test_sampled_designs_are_deterministic_and_inside_the_ranges(folder, design):
    body = f"""
        scenarios = ["base.toml"]
        design = "{design}"
        samples = 20
        design_seed = 4
        [axes]
        "controller.kp" = {{ min = 0.2, max = 1.0 }}
        "controller.ki" = {{ min = 0.1, max = 10.0, log = true }}
        "implement.sections" = {{ min = 2, max = 8 }}
        "gnss.kind" = ["rtk", "dgps"]
    """
    first, again = plan(sweep_of(folder, body)), plan(sweep_of(folder, body))
    assert [s.key for s in first] == [s.key for s in again]
    assert len(first) == 20
    points = [dict(s.axes) for s in first]
    assert all(0.2 <= p["controller.kp"] <= 1.0 for p in points)
    assert all(0.1 <= p["controller.ki"] <= 10.0 for p in points)
    assert all(type(p["implement.sections"]) is int and 2 <= p["implement.sections"] <= 8 for p in points)
    assert {p["gnss.kind"] for p in points} == {"rtk", "dgps"}
    other = plan(sweep_of(folder, body.replace("design_seed = 4", "design_seed = 5")))
    assert [s.key for s in other] != [s.key for s in first]


def test_lhs_uses_each_stratum_of_each_axis_once(folder):
    n = 10
    specs = plan(sweep_of(folder, f"""
        scenarios = ["base.toml"]
        design = "lhs"
        samples = {n}
        [axes]
        "controller.kp" = {{ min = 0.0, max = 1.0 }}
        "controller.ki" = {{ min = 0.01, max = 100.0, log = true }}
    """))
    kp = np.array([dict(s.axes)["controller.kp"] for s in specs])
    ki = np.array([dict(s.axes)["controller.ki"] for s in specs])
    assert sorted(np.floor(kp * n).astype(int)) == list(range(n))
    u = (np.log(ki) - np.log(0.01)) / (np.log(100.0) - np.log(0.01))  # log axis: strata in log
    assert sorted(np.floor(u * n).astype(int)) == list(range(n))


def test_a_design_drawing_the_same_point_twice_plans_it_once(folder):
    specs = plan(sweep_of(folder, """
        scenarios = ["base.toml"]
        design = "random"
        samples = 30
        [axes]
        "gnss.kind" = ["rtk", "dgps"]
    """))
    assert len(specs) == 2


def test_run_key_is_the_resolved_scenario(folder):
    path = str(folder / "base.toml")
    plain = scenario.load(path)
    explicit = scenario.load(path, [("implement.width_m", 12.0), ("seed", 7)])  # the defaults, spelled out
    assert _scenario_key(plain) == _scenario_key(explicit)
    assert _scenario_key(plain) != _scenario_key(scenario.load(path, [("seed", 8)]))


# --- bad input ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("body, message", [
    ('scenarios = []', "scenarios must be a non-empty list"),
    ('scenarios = ["nope.toml"]', "'nope.toml': no such file"),
    ('scenarios = ["base.toml"]\nseeds = []', "seeds must be a non-empty list"),
    ('scenarios = ["base.toml"]\nseeds = [1, -2]', "seeds must be a non-empty list of integers >= 0"),
    ('scenarios = ["base.toml"]\ndesign = "sobol"', "design must be one of grid, random, lhs, got 'sobol'"),
    ('scenarios = ["base.toml"]\nsamples = 3\n[axes]\n"controller.kp" = [1]', "samples is for design random"),
    ('scenarios = ["base.toml"]\ndesign = "random"\n[axes]\n"controller.kp" = [1]', "needs samples = N"),
    ('scenarios = ["base.toml"]\ndesign = "lhs"\nsamples = 0\n[axes]\n"controller.kp" = [1]',
     "needs samples = N >= 1, got 0"),
    ('scenarios = ["base.toml"]\ndesign = "random"\nsamples = 4', "needs at least one axis"),
    ('scenarios = ["base.toml"]\nextra = 1', "unknown key 'extra'"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = []', "'controller.kp': empty list"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = 0.5', "must be a list of values or a range"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = [0.5, "x"]', "values must be of one kind"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = { min = 0.1, max = 1.0, n = 0 }',
     "range n must be an integer >= 1, got 0"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = { min = 1.0, max = 0.1, n = 3 }',
     "range min must be <= max, got min = 1.0, max = 0.1"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = { min = 0.0, max = 1.0, n = 3, log = true }',
     "a log range needs min > 0, got min = 0.0"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = { min = 0.1, max = 1.0 }', "needs n"),
    ('scenarios = ["base.toml"]\n[axes]\n"controller.kp" = { min = 0.1, max = 1.0, n = 2, step = 1 }',
     "unknown range key 'step'"),
    ('scenarios = ["base.toml"]\n[axes]\nseed = [1, 2]', "use seeds = [...]"),
    ('scenarios = ["base.toml"]\n[report]\npareto = ["mae_kg_ha"]', "pareto must be two different metrics"),
    ('scenarios = ["base.toml"]\n[report]\npareto = ["mae_kg_ha", "ticks"]', "pareto must be two"),
])
def test_bad_sweep_files_are_named(folder, body, message):
    with pytest.raises(ScenarioError) as err:
        sweep_of(folder, body)
    assert message in str(err.value)
    assert str(err.value).startswith(str(folder / "s.toml") + ":")


@pytest.mark.parametrize("axis, message", [
    ('"controller.kpp" = [0.4]', "[controller] unknown key 'kpp'"),
    ('"implement.width_m" = [12.0, -3.0]', "[implement] Implement: width_m must be a number > 0, got -3.0"),
    ('"gnss.kind" = ["rtk", "galileo"]', "must be one of perfect, rtk, dgps, autonomous, got 'galileo'"),
    ('"implement.sections" = { min = 2.0, max = 8.0, n = 2 }', "sections must be int, got 2.0"),
    ('"tractr.working_speed_m_s" = [2.0]', "unknown key 'tractr'"),
])
def test_unknown_keys_and_out_of_range_values_are_named_like_scenario_errors(folder, axis, message):
    sw = sweep_of(folder, f'scenarios = ["base.toml"]\nseeds = [1]\n[axes]\n{axis}\n')
    with pytest.raises(ScenarioError) as err:
        plan(sw)
    text = str(err.value)
    assert text.startswith(f"{folder / 's.toml'}: scenario 'base.toml' with ")
    assert f"{folder / 'base.toml'}: " in text and message in text


def test_a_bad_end_of_a_sampled_range_fails_before_any_run(folder):
    sw = sweep_of(folder, """
        scenarios = ["base.toml"]
        design = "random"
        samples = 1
        [axes]
        "implement.width_m" = { min = -5.0, max = 12.0 }
    """)
    with pytest.raises(ScenarioError, match="width_m = -5.0.*width_m must be a number > 0"):
        plan(sw)


def test_sweep_text_errors_name_the_source():
    with pytest.raises(ScenarioError, match="^x.toml: not valid TOML"):
        parse_sweep("scenarios = [", "x.toml")


# --- statistics --------------------------------------------------------------------------------------

def test_mean_ci95_is_students_t():
    mean, half = mean_ci95(np.array([1.0, 2.0, 3.0, 4.0]))
    assert mean == 2.5
    assert half == pytest.approx(3.182446305 * np.std([1, 2, 3, 4], ddof=1) / 2)
    assert math.isnan(mean_ci95(np.array([5.0]))[1]) and math.isnan(mean_ci95(np.array([]))[0])


def test_pareto_front_respects_each_metrics_sense():
    within = np.array([90.0, 95.0, 80.0, 95.0, np.nan])  # higher is better
    distance = np.array([1.0, 2.0, 0.5, 3.0, 0.1])  # lower is better
    front = pareto_front(within, distance, "within_10pct_area_pct", "transition_distance_m_mean")
    assert front.tolist() == [True, True, True, False, False]
    bias = np.array([-1.0, 2.0, 0.5])  # best at zero, whatever the sign
    assert pareto_front(bias, np.zeros(3), "bias_kg_ha", "mae_kg_ha").tolist() == [False, False, True]


def test_configurations_group_seeds_and_skip_failed_rows():
    rows = [{"scenario": "a", "seed": s, "controller.kp": kp, "mae_kg_ha": kp * 10 + s, "status": st}
            for kp in (0.4, 0.8) for s, st in ((1, "ok"), (2, "ok"), (3, "failed"))]
    configs = configurations(rows, ["controller.kp"])
    assert [(c.axes, len(c.rows)) for c in configs] == [((("controller.kp", 0.4),), 2),
                                                        ((("controller.kp", 0.8),), 2)]
    assert configs[0].values("mae_kg_ha").tolist() == [5.0, 6.0]


def test_set_is_in_every_run_and_not_an_axis(folder):
    sw = sweep_of(folder, """
        scenarios = ["default"]
        [set]
        "controller.gains" = "manual"
        implement = { sections = 4 }
        [axes]
        "controller.kp" = [0.4, 0.8]
    """)
    assert sw.fixed == (("controller.gains", "manual"), ("implement.sections", 4))
    specs = plan(sw)
    assert [dict(s.axes) for s in specs] == [{"controller.kp": 0.4}, {"controller.kp": 0.8}]
    assert all(s.load().implement.sections == 4 and s.load().controller.gains == "manual" for s in specs)
    with pytest.raises(ScenarioError, match=r"\[set\] 'controller.kp' is also an axis"):
        sweep_of(folder, 'scenarios = ["default"]\n[set]\n"controller.kp" = 1.0\n'
                         '[axes]\n"controller.kp" = [1]\n')


def test_the_example_sweep_plans():
    sw = load_sweep(os.path.join(ROOT, "scenarios", "sweep_gains.toml"))
    specs = plan(sw)
    assert len(specs) == 54 and sw.pareto == ("within_10pct_area_pct", "mass_balance_pct")
    sc = specs[0].load()
    assert (sc.controller.gains, sc.controller.kd, sc.name) == ("manual", 0.00003, "quick_rectangle")


def test_variant_groups_cut_large_groups_so_each_worker_has_a_part(folder):
    """One drive per scenario and seed; with fewer groups than workers the groups are cut into
    consecutive parts of about equal size, none below min_part, every spec in exactly one part."""
    sw = sweep_of(folder, """
        scenarios = ["base.toml"]
        seeds = [1, 2]
        [axes]
        "controller.kp" = { min = 0.1, max = 1.0, n = 10 }
    """)
    specs = plan(sw)
    assert [len(g) for g in variant_groups(specs)] == [10, 10]
    assert [len(g) for g in variant_groups(specs, workers=2)] == [10, 10]
    parts = variant_groups(specs, workers=5, min_part=3)
    assert [len(p) for p in parts] == [3, 3, 4, 3, 3, 4]
    assert [s for p in parts for s in p] == [s for g in variant_groups(specs) for s in g]
    assert all(len({(s.scenario, s.seed) for s in p}) == 1 for p in parts)
    assert [len(p) for p in variant_groups(specs, workers=8, min_part=4)] == [5, 5, 5, 5]
    assert [len(p) for p in variant_groups(specs, workers=8, min_part=20)] == [10, 10]
