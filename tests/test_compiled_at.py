"""The observer's compiled step called with its arrays by address (rtlift.observer.compiled_at):
bit for bit the dispatcher's call with the 20 (22) arrays, on both structures with every stage;
an argument of another kind is never bound by address."""

from __future__ import annotations

import numpy as np
import pytest

from rtlift.observer import Observer, compiled_at
from rtlift.observer import compiled as cs
from testkit.synthetic import interaction_model, make_model, with_effects
from tests.test_observer_compiled import CONFIGS, _inputs

CONFIG = CONFIGS["all_states"]


@pytest.mark.parametrize("structure", ["paper", "paper_effects", "interaction_effects"])
def test_the_step_by_address_is_the_dispatchers_bit_for_bit(rng, structure):
    model = {"paper": lambda: make_model(rng),
             "paper_effects": lambda: with_effects(make_model(rng), True, (0, 1, 2), 2),
             "interaction_effects": lambda: with_effects(interaction_model(rng), True, (1, 2), 2)}[structure]()
    by_address, one_by_one = Observer(model, CONFIG), Observer(model.copy(), CONFIG)
    interaction = "interaction" in structure
    assert by_address._kernel[0] is (cs.observer_step_interaction if interaction else cs.observer_step)
    wrapper = compiled_at.observer_step_interaction_at if interaction else compiled_at.observer_step_at
    assert by_address._at[0] is wrapper
    one_by_one._at = ()                                  # numba's dispatcher, the arrays one by one
    cmu, env, z = _inputs(rng, 1500)
    a = np.array([by_address.step(c, e, m).as_tuple() for c, e, m in zip(cmu, env, z, strict=True)])
    b = np.array([one_by_one.step(c, e, m).as_tuple() for c, e, m in zip(cmu, env, z, strict=True)])
    assert np.isfinite(a[:, 0]).all() and np.ptp(a[:, 0]) > 0.01     # the estimate moved
    np.testing.assert_array_equal(a, b)                  # NaN where NaN, every other bit equal
    np.testing.assert_array_equal(by_address.get_state(), one_by_one.get_state())


def test_arguments_of_another_kind_are_not_bound_by_address(rng):
    """A Fortran-ordered, read-only, float32 or 3-D array, or one array too few: no binding."""
    obs = Observer(make_model(rng), CONFIG)
    step, args, _ = obs._kernel
    assert compiled_at.bind(step, args)
    m = next(i for i, a in enumerate(args) if a.ndim == 2 and a.shape[0] > 1 and a.shape[1] > 1)
    readonly = args[0].copy()
    readonly.flags.writeable = False
    for i, bad in ((m, np.asfortranarray(args[m])), (0, readonly), (0, args[0].astype(np.float32)),
                   (0, args[0].reshape(1, 1, -1))):
        assert compiled_at.bind(step, args[:i] + (bad,) + args[i + 1:]) == ()
    assert compiled_at.bind(step, args[:-1]) == ()
    assert compiled_at.bind(cs.observer_touch, args) == ()
