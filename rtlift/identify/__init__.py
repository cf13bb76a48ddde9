"""Identification of the hybrid model from recorded experiments.

- :mod:`.static_map` — static map ΔCL(Cμ), hysteresis report, N(Cμ) = ΔCL/Cμ table;
- :mod:`.kernel` — single-burst kernel h and φ (paper eq. 1);
- :mod:`.pem` — LTI of the Wiener model by output-error PEM (Ljung);
- :mod:`.poles` — the LTI in canonical form and its stable pole parametrisation;
- :mod:`.problem` — the PEM's output error with the linear parameters eliminated;
- :mod:`.uncertainty` — the PEM's parameter, pole and DC-gain uncertainty;
- :mod:`.order` — the Wiener LTI's order by held-out error;
- :mod:`.highpass` — HPF order and cutoff by held-out error;
- :mod:`.campaign` — the whole hybrid from the static, single-burst and training records.
"""

from rtlift.identify.campaign import Identification, IdentifyOptions, identify_hybrid
from rtlift.identify.kernel import SingleBurstKernel, fit_kernel
from rtlift.identify.pem import PEMResult, fit_wiener
from rtlift.identify.poles import CanonicalLTI
from rtlift.identify.static_map import StaticMap, fit_static_map, isotonic_increasing

__all__ = [
    "CanonicalLTI", "Identification", "IdentifyOptions", "PEMResult", "SingleBurstKernel",
    "StaticMap", "fit_kernel", "fit_static_map", "fit_wiener", "identify_hybrid",
    "isotonic_increasing",
]
