"""The effects and structures (:mod:`rtlift.effects`): one module and one class each, every table
of them derived from the classes, every part a class declares present and agreeing with the
stages, the observer, the generic diagnosis, the bench and the docs; no effect name typed
outside its module."""

from __future__ import annotations

import ast
import inspect
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from firmware_io.calibration import Calibration
from hil_sim import effects as bench_effects
from hil_sim.experiments import Bench as BenchRig
from hil_sim.plant import PlantParams
from rtlift.blocks.stage_base import InputStage, OutputStage
from rtlift.blocks.stages import STAGES
from rtlift.blocks.wiener import NONLINEARITIES
from rtlift.core.effects import Interval
from rtlift.core.rate import FS_HZ as FS
from rtlift.core.registry import LIMIT_FORMS, MODEL_STRUCTURE_NAMES, MODEL_STRUCTURES
from rtlift.effects import BY_NAME, CATALOG, EFFECT_NAMES, EFFECTS, ENTRIES, PATHS, SCHEMAS, STRUCTURES
from rtlift.effects.base import Effect, StateBlock, Structure
from rtlift.observer.layout import OBSERVER_FORMS
from rtlift.sysid import diagnose as sysid

ROOT = Path(__file__).resolve().parents[1]
NAMES = [e.name for e in ENTRIES]
TABLE = {"cmu": [0.0, 1.0], "gain": [1.0, 0.8], "y": [0.0, 1.0], "f": [0.0, 0.9],
         "fs_hz": FS, "time_constant_s": 0.1}
"""A base Wiener table for the nonlinearity forms (their effect's defaults added)."""


def test_each_entry_is_one_class_in_a_module_of_its_own_named_after_it():
    for e in ENTRIES:
        module = type(e).__module__
        assert module == f"rtlift.effects.{e.name}", (e.name, module)
        assert sum(isinstance(v, type) and issubclass(v, (Effect, Structure)) and v.__module__ == module
                   for v in vars(sys.modules[module]).values()) == 1, module


def test_the_tables_are_derived_from_the_classes():
    classes = {c for base in (Effect, Structure) for c in base.__subclasses__()}
    assert {type(e) for e in ENTRIES} == classes
    for kind in (EFFECTS, STRUCTURES):
        rows = [e.row for e in kind]
        assert rows == sorted(set(rows)), rows
    assert tuple(EFFECTS) + tuple(STRUCTURES) == ENTRIES and set(BY_NAME) == set(NAMES)
    assert dict(SCHEMAS) == {e.name: e.schema for e in EFFECTS}


def test_names_are_unique_and_kinds_known():
    assert len(set(NAMES)) == len(NAMES)
    assert {e.kind for e in ENTRIES} == {"effect", "structure"}
    assert all(e.doc and "\n" not in e.doc and e.schema.name == e.name and e.schema.meaning == e.doc
               for e in ENTRIES)


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_schema_has_units_and_its_defaults_lie_in_its_ranges(entry):
    s = entry.schema
    assert set(s.units) == set(s.ranges)
    for d in (s.defaults, *s.alternatives):
        assert all(s.ranges[k][0] <= v <= s.ranges[k][1] for k, v in d.items()), d


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_stage_is_built_from_its_defaults(entry):
    assert entry.path in PATHS and entry.stages
    for cls in entry.stages:
        if entry.path == "nonlinearity":
            assert NONLINEARITIES[cls.form] is cls
            nl = cls.from_dict({**TABLE, **entry.schema.defaults})
            assert np.isfinite(nl.simulate(np.linspace(0, 1, 20), np.linspace(0, 1, 20))).all()
            continue
        assert STAGES[entry.name] is cls and cls.name == entry.name
        assert tuple(getattr(cls, "per_record", ())) == entry.per_record
        stage = cls.from_params(dict(entry.schema.defaults), FS)
        if entry.path == "input":
            assert isinstance(stage, InputStage) and not isinstance(stage, OutputStage)
            out = stage.simulate(np.ones(50), np.ones(50))[0]
        else:
            assert isinstance(stage, OutputStage) and stage.kind == entry.path
            out = stage.simulate(np.ones(50))
        assert np.isfinite(out).all()


def test_the_stages_by_name_are_the_effects_and_the_interaction_structures():
    not_effects = {"delivered_momentum", "delivered_envelope", "onset_hold"}   # onset_hold: the identification's
    assert set(STAGES) - not_effects == {e.name for e in EFFECTS if e.path != "nonlinearity"}


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effect_declares_its_fit_evidence_and_parameters_spent(entry):
    cls = type(entry)
    assert cls.fit is not Effect.fit and cls.evidence is not Effect.evidence
    assert entry.n_params(dict(entry.schema.defaults)) > 0
    assert set(entry.excludes) <= set(EFFECT_NAMES) - {entry.name}


def test_the_excluded_pairs():
    assert {frozenset((e.name, x)) for e in EFFECTS for x in e.excludes} == \
        {frozenset(("hysteresis", "output_nonlinearity"))}


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_explained_bands(entry):
    if entry.bands is None:
        assert entry.name not in ("sensor_resonance", "periodic_disturbance")
        return
    bands = entry.bands(dict(entry.schema.defaults), 0.1)
    assert bands and all(0 < lo < hi for lo, hi in bands)


def test_the_catalog_holds_every_effect_in_the_signal_paths_order():
    """By path, INTERFACES.md's order within one (the order a combination is built in, which the
    reports' numbers depend on: pinned for the effects of today; a new one goes where its path
    and row put it)."""
    assert [e.name for e in CATALOG] == list(EFFECT_NAMES)
    assert sorted(CATALOG, key=lambda e: (PATHS.index(e.path), EFFECTS.index(e))) == list(CATALOG)
    today = ["delay", "actuator_fade", "hysteresis", "output_nonlinearity", "sensor_resonance", "zero_drift",
             "periodic_disturbance"]
    assert [n for n in EFFECT_NAMES if n in today] == today


@pytest.mark.parametrize("entry", EFFECTS, ids=lambda e: e.name)
def test_an_effects_observer_form_returns_a_state_block_or_none(entry):
    if not entry.observed:
        assert entry.name not in OBSERVER_FORMS
        return
    form = OBSERVER_FORMS[entry.name]
    block = form(dict(entry.schema.defaults), FS)
    assert block is None or isinstance(block, StateBlock) and block.F.shape == (block.size, block.size)
    assert (block is None) == (entry.name == "zero_drift")


@pytest.mark.parametrize("name", list(bench_effects.EFFECTS))
def test_the_bench_injects_an_effect_with_the_effects_parameters(name):
    """The bench declares its own injection (it is the truth plant, below rtlift's model):
    the same parameters, defaults, ranges and units as the effect's, intervals that hold the
    documented ranges, and its physics."""
    info, effect = bench_effects.EFFECTS[name], BY_NAME[name]
    s, b = info.schema, effect.schema
    assert (dict(s.defaults), dict(s.ranges), dict(s.units)) == (dict(b.defaults), dict(b.ranges), dict(b.units))
    assert [dict(a) for a in s.alternatives] == [dict(a) for a in b.alternatives]
    bench = info.bench
    assert set(bench.accepts) <= set(s.ranges) | set(bench.only)
    for key, (lo, hi) in s.ranges.items():
        if key in bench.accepts:
            assert lo in bench.accepts[key] and hi in bench.accepts[key], key
    parsed = bench_effects.parse_effect(name)
    assert dict(parsed.params) == dict(b.defaults)
    rig = BenchRig(0, [parsed], Calibration())
    if bench.stage == "plant":
        assert name not in bench_effects.PROCESSORS and bench.plant
        assert set(bench.plant) <= set(s.ranges)
        for key, to in bench.plant.items():      # the plant at rest has none of it
            assert getattr(rig.plant.params, to) == getattr(PlantParams(), to) + parsed.params[key] != 0.0
    else:
        assert bench_effects.PROCESSORS[name].name == name and not bench.plant
    n = 400
    gate = np.arange(n) % 40 < 4
    run = rig.process(np.arange(n) / FS, np.full(n, 2.0), gate, {})
    assert run.counts.shape[0] == n and np.isfinite(run.dcl_true).all()


def test_the_bench_injects_only_effects_in_their_order():
    assert set(bench_effects.PROCESSORS) <= set(bench_effects.EFFECTS)
    assert list(bench_effects.EFFECTS) == [e.name for e in EFFECTS if e.name in bench_effects.EFFECTS]
    assert "output_nonlinearity" not in bench_effects.EFFECTS      # a model's form, not a plant's


@pytest.mark.parametrize("text, inside, outside", [("(0, 10]", [10.0, 1e-9], [0.0, 10.1, float("nan")]),
                                                   ("[0, inf)", [0.0, 1e300], [-1e-9, float("inf")])])
def test_an_interval_holds_what_its_brackets_say(text, inside, outside):
    assert all(v in Interval(text) for v in inside) and not any(v in Interval(text) for v in outside)


@pytest.mark.parametrize("entry", STRUCTURES, ids=lambda e: e.name)
def test_a_structures_forms_exist(entry):
    assert entry.forms and entry.how and sysid.HOW[entry.name] == entry.how
    for structure, _ in entry.forms:
        assert structure in MODEL_STRUCTURE_NAMES


def test_the_generic_diagnosis_tries_every_structure():
    tried = {name for name, _ in sysid.FORMS} | {sysid.SATURATION.name}
    assert tried == {e.name for e in STRUCTURES}
    assert sysid.SATURATED_FORMS == LIMIT_FORMS == BY_NAME["saturation"].forms


@pytest.mark.parametrize("structure", MODEL_STRUCTURE_NAMES)
@pytest.mark.parametrize("where", ["output", "state"])
def test_identification_takes_a_limit_exactly_where_saturation_is_tried(structure, where):
    """identify_siso's own check of where a limit can sit agrees with the saturation structure's
    forms (a record too short to identify: the check of the form comes first)."""
    from rtlift.core.records import SisoRecord
    from rtlift.sysid.identify import identify_siso

    short = SisoRecord(np.arange(10) / 10.0, np.zeros(10), np.zeros(10))
    with pytest.raises(ValueError) as info:
        identify_siso(short, structure, limits=(0.0, 1.0), where=where)
    assert ("too short" in str(info.value)) == ((structure, where) in BY_NAME["saturation"].forms), info.value


def test_the_model_structures_are_built_by_their_classes():
    from rtlift.model.siso import MODEL_CLASSES, SISO_MODELS, STRUCTURES

    assert STRUCTURES == MODEL_STRUCTURE_NAMES == tuple(MODEL_CLASSES)
    for s in MODEL_STRUCTURES:
        cls = MODEL_CLASSES[s.name]
        own = cls.structure if isinstance(cls.structure, str) else None   # SisoModel's: by its g2
        assert cls in SISO_MODELS and own in (s.name, None) and callable(cls.from_dict)   # what a file is built with
    assert {s: c.__name__ for s, c in MODEL_CLASSES.items()} == {
        "wiener": "SisoModel", "wiener_hammerstein": "SisoModel", "nonlinear_feedback": "FeedbackModel",
        "store_chain": "StoreChainModel"}


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


# ------------------------------------------------------------------ no name typed elsewhere
FILE_KEYS = {("rtlift/identify/campaign.py", "hysteresis"): "the model file's static-map hysteresis table",
             ("rtlift/identify/interaction.py", "hysteresis"): "the model file's static-map hysteresis table",
             ("rtlift/model/siso.py", "saturation"): "a generic model file's limits",
             ("rtlift/model/siso_file.py", "saturation"): "a generic model file's limits"}
"""(file, name) of string constants that are a file format's keys, not the effect's name."""


def _typed_names() -> list[tuple[str, str]]:
    """(file, name) of every string constant in rtlift/ outside rtlift/effects/ that is exactly
    a registered name (docstrings and messages that mention one are prose, not a name typed).
    A stage's own ``name`` in its module of rtlift/blocks is the model file's key, which the
    effect takes from it; a model structure's name is the structure's (``nonlinear_feedback``)."""
    names = set(NAMES) - set(MODEL_STRUCTURE_NAMES)
    stage_files = {Path(inspect.getsourcefile(e.stages[0])).relative_to(ROOT).as_posix(): e.name
                   for e in EFFECTS if e.path != "nonlinearity"}
    out = []
    for path in sorted((ROOT / "rtlift").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("rtlift/effects/"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and node.value in names:
                if stage_files.get(rel) == node.value or (rel, node.value) in FILE_KEYS:
                    continue
                out.append((rel, node.value))
    return out


def test_no_effect_name_is_typed_outside_its_module():
    assert _typed_names() == []


# ------------------------------------------------------------------ a new effect is one module
TOY = '''
"""A toy effect: a gain on the input, its stage its own (the dry run of tests/test_effects_modules.py)."""

import numpy as np

from rtlift.blocks.stage_base import InputStage
from rtlift.effects.base import Effect, no_print
from rtlift.effects.surgery import Fitted, augment


class ToyGain(InputStage):
    """Cμ′ = g Cμ, Cμ_env′ = g Cμ_env."""

    name = "toy_gain"

    def __init__(self, gain, fs_hz):
        self.gain = gain

    @classmethod
    def from_params(cls, params, fs_hz):
        return cls(float(params["gain"]), fs_hz)

    def params(self):
        return {"gain": self.gain}

    def step(self, cmu, env):
        return self.gain * cmu, self.gain * env

    def simulate(self, cmu, env):
        return self.gain * np.asarray(cmu), self.gain * np.asarray(env)

    def get_state(self):
        return np.zeros(0)

    def set_state(self, state):
        pass


class ToyGainEffect(Effect):
    name = ToyGain.name
    row = 75
    meaning = "a toy gain on the input"
    params = {"gain": (1.2, 1.0, 1.5, "1")}
    path = "input"
    stages = (ToyGain,)
    spent = 1

    def fit(self, base, train, ctx):
        stage = ToyGain(1.2, ctx.fs)
        return Fitted(self.name, augment(base, input_stage=stage), stage.params())

    def evidence(self, tests, fp, fitted):
        return no_print("a toy")
'''

DRY_RUN = '''
import sys
from rtlift.blocks.stages import STAGES
from rtlift.effects import BY_NAME, CATALOG, SCHEMAS
from rtlift.effects.surgery import augment
from rtlift.effects.toy_gain import ToyGain
from rtlift.model.modelfile import load_model, save_model
from rtlift.observer.layout import OBSERVER_FORMS
print("stages", STAGES["toy_gain"].__name__)
print("catalog", [e.name for e in CATALOG][:3])
print("schemas", dict(SCHEMAS["toy_gain"].defaults))
print("observer", "toy_gain" in OBSERVER_FORMS, BY_NAME["toy_gain"].n_params({}))
save_model(augment(load_model(sys.argv[1]), input_stage=ToyGain(1.25, 400.0)), sys.argv[2])
'''

LOAD_BACK = '''
import sys
import numpy as np
from rtlift.model.modelfile import load_model
before = "rtlift.effects" in sys.modules
m = load_model(sys.argv[1])
cmu = np.full(40, 0.002)
print("loaded", before, [s.name for s in m.input_stages], m.input_stages[-1].gain, "rtlift.effects" in sys.modules)
a, b = m.simulate(cmu, cmu).total, load_model(sys.argv[2]).reference_simulate(1.25 * cmu, 1.25 * cmu).total
print("gained", m.compiled, bool(np.max(np.abs(a - b)) <= 1e-12 * np.max(np.abs(b))), bool(np.max(np.abs(b)) > 0))
'''

NO_PROVIDER = '''
import sys
import rtlift.core.registry as r
r._STAGE_PROVIDERS.clear()
from rtlift.core.errors import ModelFileError
from rtlift.model.modelfile import load_model
try:
    load_model(sys.argv[1])
except ModelFileError as exc:
    print(exc)
'''


def test_a_new_effect_is_one_module_in_the_effects_package(tmp_path):
    """The dry run: a copy of rtlift with the toy effect's one module in rtlift/effects/, its
    streaming stage defined there too; every derived table holds it, a model the effect augments
    is saved and, in a fresh process that imports only the model layer, loads back (the stage
    found through the stage provider ``import rtlift`` hands down, :mod:`rtlift.core.registry`)
    and gives what the stage's gain on the inputs of the base model gives; without the provider
    the reader says in one line what to import; and no other file changes."""
    shutil.copytree(ROOT / "rtlift", tmp_path / "rtlift", ignore=shutil.ignore_patterns("__pycache__", "data"))
    (tmp_path / "rtlift" / "effects" / "toy_gain.py").write_text(TOY, encoding="utf-8")
    env = {"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    base, toy = ROOT / "tests" / "data" / "bench_model.json", tmp_path / "toy_model.json"

    def run(code, *args):
        return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                              cwd=tmp_path, env=env)

    out = run(DRY_RUN, base, toy)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        "stages ToyGain", "catalog ['delay', 'actuator_fade', 'toy_gain']", "schemas {'gain': 1.2}",
        "observer False 1"]
    out = run(LOAD_BACK, toy, base)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ["loaded False ['delay', 'toy_gain'] 1.25 True", "gained False True True"]
    out = run(NO_PROVIDER, toy)
    assert out.returncode == 0, out.stderr
    assert "unknown augmentation 'toy_gain'" in out.stdout and "import rtlift.effects" in out.stdout, out.stdout
    assert out.stdout.count("\n") == 1
