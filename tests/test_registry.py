"""The effect registry (:mod:`rtlift.core.registry`): every record has every part it claims, every
other table of effects is derived from it or agrees with it, and the docs name what it holds."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from firmware_io.calibration import Calibration
from hil_sim import effects as bench_effects
from hil_sim.experiments import Bench as BenchRig
from hil_sim.plant import PlantParams
from rtlift.blocks.stage import InputStage, OutputStage
from rtlift.blocks.stages import STAGES
from rtlift.blocks.wiener import NONLINEARITIES
from rtlift.core.effects import Interval
from rtlift.core.rate import FS_HZ as FS
from rtlift.core.registry import (
    EFFECTS,
    ENTRIES,
    MODEL_STRUCTURE_NAMES,
    MODEL_STRUCTURES,
    PATHS,
    REGISTRY,
    SCHEMAS,
    STRUCTURES,
    in_signal_order,
    resolve,
)
from rtlift.diagnose.catalog import CATALOG
from rtlift.diagnose.catalog import EFFECTS as DIAGNOSED
from rtlift.observer.layout import OBSERVER_FORMS, StateBlock
from rtlift.sysid import diagnose as sysid

ROOT = Path(__file__).resolve().parents[1]
NAMES = [e.name for e in REGISTRY]
TABLE = {"cmu": [0.0, 1.0], "gain": [1.0, 0.8], "y": [0.0, 1.0], "f": [0.0, 0.9],
         "fs_hz": FS, "time_constant_s": 0.1}
"""A base Wiener table for the nonlinearity forms (their effect's defaults added)."""


HOMES = {"stages": ("rtlift.blocks.",), "fit": ("rtlift.diagnose.", "rtlift.sysid."),
         "evidence": ("rtlift.diagnose.", "rtlift.sysid.", "rtlift.residual."), "observer": ("rtlift.observer.",)}
"""Where each part's code lives: the layer that resolves it (tests/test_layers.py's order)."""


def test_each_part_names_code_in_the_layer_that_resolves_it():
    for e in REGISTRY:
        parts = {"stages": e.stages, "observer": (e.observer,) if e.observer else (),
                 "fit": (e.diagnosis.fit,), "evidence": (e.diagnosis.evidence,)}
        for part, paths in parts.items():
            assert all(p.startswith(HOMES[part]) for p in paths), (e.name, part, paths)


def test_names_are_unique_and_kinds_known():
    assert len(set(NAMES)) == len(NAMES)
    assert {e.kind for e in REGISTRY} == {"effect", "structure"}
    assert all(e.doc and "\n" not in e.doc and e.schema.name == e.name for e in REGISTRY)


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_schema_has_units_and_its_defaults_lie_in_its_ranges(entry):
    s = entry.schema
    assert set(s.units) == set(s.ranges)
    for d in (s.defaults, *s.alternatives):
        assert all(s.ranges[k][0] <= v <= s.ranges[k][1] for k, v in d.items()), d


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_stage_is_built_from_its_defaults(entry):
    assert entry.path in PATHS and entry.stages
    for path in entry.stages:
        cls = resolve(path)
        if entry.path == "nonlinearity":
            assert NONLINEARITIES[cls.form] is cls
            nl = cls.from_dict({**TABLE, **entry.schema.defaults})
            assert np.isfinite(nl.simulate(np.linspace(0, 1, 20), np.linspace(0, 1, 20))).all()
            continue
        assert STAGES[entry.name] is cls and cls.name == entry.name
        stage = cls.from_params(dict(entry.schema.defaults), FS)
        if entry.path == "input":
            assert isinstance(stage, InputStage) and not isinstance(stage, OutputStage)
            out = stage.simulate(np.ones(50), np.ones(50))[0]
        else:
            assert isinstance(stage, OutputStage) and stage.kind == entry.path
            out = stage.simulate(np.ones(50))
        assert np.isfinite(out).all()


def test_the_stages_by_name_are_the_registrys_and_the_interaction_structures():
    not_effects = {"delivered_momentum", "delivered_envelope"}
    assert set(STAGES) - not_effects == {e.name for e in EFFECTS if e.path != "nonlinearity"}


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_fit_and_evidence_are_the_catalogs(entry):
    d, eff = entry.diagnosis, DIAGNOSED[entry.name]
    assert eff.fit is resolve(d.fit) and callable(eff.fit)
    assert eff.evidence is resolve(d.evidence) and callable(eff.evidence)
    params = dict(entry.schema.defaults)
    assert eff.n_params(params) == (d.n_params if isinstance(d.n_params, int) else resolve(d.n_params)(params)) > 0
    assert set(d.excludes) <= set(DIAGNOSED) and all(entry.name in DIAGNOSED[x].excludes for x in d.excludes)
    assert eff.schema is SCHEMAS[entry.name]


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_explained_bands_are_the_catalogs(entry):
    eff = DIAGNOSED[entry.name]
    if entry.diagnosis.bands is None:
        assert eff.bands is None
        return
    assert eff.bands is resolve(entry.diagnosis.bands)
    bands = eff.bands(dict(entry.schema.defaults), 0.1)
    assert bands and all(0 < lo < hi for lo, hi in bands)


def test_the_catalog_holds_every_effect_in_the_signal_paths_order():
    assert [e.name for e in CATALOG] == [e.name for e in in_signal_order()] == [
        "delay", "actuator_fade", "hysteresis", "output_nonlinearity", "sensor_resonance", "zero_drift",
        "periodic_disturbance"]


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_observer_form_returns_a_state_block_or_none(entry):
    if entry.observer is None:
        assert entry.name not in OBSERVER_FORMS
        return
    form = OBSERVER_FORMS[entry.name]
    assert form is resolve(entry.observer)
    block = form(dict(entry.schema.defaults), FS)
    assert block is None or isinstance(block, StateBlock) and block.F.shape == (block.size, block.size)


@pytest.mark.parametrize("entry", [e for e in EFFECTS if e.bench], ids=lambda e: e.name)
def test_the_bench_injects_an_effect_with_its_defaults(entry):
    info = bench_effects.EFFECTS[entry.name]
    assert info.schema is entry.schema and info.stage == entry.bench.stage
    assert set(entry.bench.accepts) <= set(entry.schema.ranges) | set(entry.bench.only)
    for key, (lo, hi) in entry.schema.ranges.items():
        if key in entry.bench.accepts:
            assert lo in entry.bench.accepts[key] and hi in entry.bench.accepts[key], key
    effect = bench_effects.parse_effect(entry.name)
    assert dict(effect.params) == dict(entry.schema.defaults)
    rig = BenchRig(0, [effect], Calibration())
    if entry.bench.stage == "plant":
        assert entry.name not in bench_effects.PROCESSORS and entry.bench.plant
        assert set(entry.bench.plant) <= set(entry.schema.ranges)
        for key, to in entry.bench.plant.items():      # the plant at rest has none of it
            assert getattr(rig.plant.params, to) == getattr(PlantParams(), to) + effect.params[key] != 0.0
    else:
        assert bench_effects.PROCESSORS[entry.name].name == entry.name and not entry.bench.plant
    n = 400
    gate = np.arange(n) % 40 < 4
    run = rig.process(np.arange(n) / FS, np.full(n, 2.0), gate, {})
    assert run.counts.shape[0] == n and np.isfinite(run.dcl_true).all()


def test_the_bench_injects_exactly_the_registrys_bench_effects():
    assert list(bench_effects.EFFECTS) == [e.name for e in EFFECTS if e.bench]
    assert set(bench_effects.PROCESSORS) == {e.name for e in EFFECTS if e.bench and e.bench.stage != "plant"}


@pytest.mark.parametrize("text, inside, outside", [("(0, 10]", [10.0, 1e-9], [0.0, 10.1, float("nan")]),
                                                   ("[0, inf)", [0.0, 1e300], [-1e-9, float("inf")])])
def test_an_interval_holds_what_its_brackets_say(text, inside, outside):
    assert all(v in Interval(text) for v in inside) and not any(v in Interval(text) for v in outside)


@pytest.mark.parametrize("entry", STRUCTURES, ids=lambda e: e.name)
def test_a_structures_forms_fit_and_evidence_exist(entry):
    assert entry.forms and entry.how and sysid.HOW[entry.name] == entry.how
    for structure, _ in entry.forms:
        assert structure in MODEL_STRUCTURE_NAMES
    assert callable(resolve(entry.diagnosis.fit)) and callable(resolve(entry.diagnosis.evidence))


def test_the_generic_diagnosis_tries_every_structure():
    tried = {name for name, _ in sysid.FORMS} | {sysid.SATURATION.name}
    assert tried == {e.name for e in STRUCTURES}
    assert sysid.SATURATED_FORMS == ENTRIES["saturation"].forms


@pytest.mark.parametrize("structure", MODEL_STRUCTURE_NAMES)
@pytest.mark.parametrize("where", ["output", "state"])
def test_identification_takes_a_limit_exactly_where_saturation_is_tried(structure, where):
    """identify_siso's own check of where a limit can sit agrees with the registry's forms (a
    record too short to identify: the check of the form comes first)."""
    from rtlift.core.records import SisoRecord
    from rtlift.sysid.identify import identify_siso

    short = SisoRecord(np.arange(10) / 10.0, np.zeros(10), np.zeros(10))
    with pytest.raises(ValueError) as info:
        identify_siso(short, structure, limits=(0.0, 1.0), where=where)
    assert ("too short" in str(info.value)) == ((structure, where) in ENTRIES["saturation"].forms), info.value


def test_the_model_structures_are_built_by_their_classes():
    from rtlift.model.siso import MODEL_CLASSES, SISO_MODELS, STRUCTURES

    assert STRUCTURES == MODEL_STRUCTURE_NAMES == tuple(MODEL_CLASSES)
    for s in MODEL_STRUCTURES:
        cls = resolve(s.model)
        own = cls.structure if isinstance(cls.structure, str) else None   # SisoModel's: by its g2
        assert cls in SISO_MODELS and own in (s.name, None)
        assert MODEL_CLASSES[s.name] is cls and callable(cls.from_dict)    # what a model file is built with


def _interfaces_table() -> list[str]:
    text = (ROOT / "docs" / "INTERFACES.md").read_text(encoding="utf-8")
    head = text.index("| name | parameters | physical meaning |")
    rows = text[head:].split("\n\n", 1)[0].splitlines()[2:]
    return [re.match(r"\| `(\w+)` \|", row).group(1) for row in rows]


def test_interfaces_md_names_exactly_the_registered_effects_and_structures():
    assert _interfaces_table() == NAMES


def test_interfaces_md_names_exactly_the_model_structures():
    text = (ROOT / "docs" / "INTERFACES.md").read_text(encoding="utf-8")
    assert "--structure " + "|".join(MODEL_STRUCTURE_NAMES) + "\n" in text


TOY = '''
import numpy as np
from rtlift.blocks.stage import InputStage


class ToyGain(InputStage):
    name = "toy_gain"

    def __init__(self, gain, fs_hz):
        self.gain = gain

    @classmethod
    def from_params(cls, params, fs_hz):
        return cls(float(params["gain"]), fs_hz)

    def params(self):
        return {"gain": self.gain}

    def simulate(self, cmu, env):
        return self.gain * np.asarray(cmu), self.gain * np.asarray(env)

    def get_state(self):
        return np.zeros(0)

    def set_state(self, state):
        pass


def fit_toy(base, train, ctx):
    return "a toy"


def evidence_toy(tests, fp, fitted):
    raise NotImplementedError
'''

DRY_RUN = '''
import importlib.util, sys
path = sys.argv[1]
source = open(path, encoding="utf-8").read()
entry = (\'    _entry("toy_gain", "effect", "a toy gain on the input", {"gain": (1.2, 1.0, 1.5, "1")}, \'
         \'path="input", stages=("toy_effect:ToyGain",), \'
         \'diagnosis=Diagnosis("toy_effect:fit_toy", "toy_effect:evidence_toy", 1), \'
         \'bench=_bench("actuator", gain="(0, 2)")),\\n)\\n\\nMODEL_STRUCTURES\')
assert source.count(")\\n\\nMODEL_STRUCTURES") == 1
spec = importlib.util.spec_from_loader("rtlift.core.registry", loader=None, origin=path)
module = importlib.util.module_from_spec(spec)
sys.modules["rtlift.core.registry"] = module
exec(compile(source.replace(")\\n\\nMODEL_STRUCTURES", entry), path, "exec"), module.__dict__)
from rtlift.blocks.stages import STAGES
from rtlift.diagnose.catalog import CATALOG
from hil_sim.effects import EFFECTS, PROCESSORS, parse_effect
from rtlift.core.registry import SCHEMAS
print("schemas", "toy_gain" in SCHEMAS)
print("stages", STAGES["toy_gain"].__name__)
print("catalog", [e.name for e in CATALOG][:3])
print("bench", EFFECTS["toy_gain"].stage, dict(parse_effect("toy_gain").params))
print("processor", "toy_gain" in PROCESSORS)
'''


def test_a_new_effect_is_one_registry_entry_and_its_code(tmp_path):
    """The dry run: a toy effect's record added to the registry's source, its stage and fit in one
    new module; every derived table holds it, but for the bench's own physics (hil_sim's
    processors), which a new bench effect adds by hand (the test above then says so)."""
    (tmp_path / "toy_effect.py").write_text(TOY, encoding="utf-8")
    out = subprocess.run([sys.executable, "-c", DRY_RUN, str(ROOT / "rtlift" / "core" / "registry.py")],
                         capture_output=True, text=True, cwd=ROOT,
                         env={"PYTHONPATH": f"{ROOT}:{tmp_path}", "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        "schemas True", "stages ToyGain", "catalog ['delay', 'actuator_fade', 'toy_gain']",
        "bench actuator {'gain': 1.2}", "processor False"]
