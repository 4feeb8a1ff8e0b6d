"""Linear attenuation of the materials of X-ray hardware (NIST XCOM data, 30–100 keV).

:func:`attenuation_per_mm` interpolates (log–log) the NIST XCOM / Hubbell & Seltzer (NISTIR 5632)
mass attenuation coefficients μ/ρ (cm²/g, coherent scattering included) at 30–100 keV and
multiplies by a density. At 60 keV — the effective energy :class:`core.render.HUTransfer`
assumes (μ_water = 0.0206 /mm) — stainless steel (≈ iron, ρ 7.9 g/cm³) has μ ≈ 0.95 /mm; the
often-quoted 2–3 /mm holds at 40–45 keV, the mean energy of a lightly filtered 60–70 kVp beam.
A scene should take water and steel at the *same* energy; the default here is 60 keV.

Calibration objects (:mod:`core.calibration.hardware`) and the synthetic generator
(:mod:`core.synthetic`) take their attenuation from here.
"""

from __future__ import annotations

import numpy as np

from .._validate import positive

__all__ = ["DENSITY_G_CM3", "MASS_ATTENUATION_CM2_G", "attenuation_per_mm"]

_E_KEV = np.array([30.0, 40.0, 50.0, 60.0, 80.0, 100.0])
#: μ/ρ (cm²/g) at 30, 40, 50, 60, 80, 100 keV (NIST XCOM, total with coherent scattering).
MASS_ATTENUATION_CM2_G = {
    "water": (0.3756, 0.2683, 0.2269, 0.2059, 0.1837, 0.1707),
    "steel": (8.176, 3.629, 1.958, 1.205, 0.5952, 0.3717),  # iron
    "aluminium": (1.128, 0.5685, 0.3681, 0.2778, 0.2018, 0.1704),
    "lead": (30.32, 14.36, 8.041, 5.021, 2.419, 5.549),  # K edge at 88 keV
    "carbon": (0.2562, 0.2076, 0.1871, 0.1753, 0.1610, 0.1514),
}
#: Default densities (g/cm³): AISI 304 steel, 6061 Al, lead, carbon-fibre composite.
DENSITY_G_CM3 = {"water": 1.0, "steel": 7.9, "aluminium": 2.70, "lead": 11.35, "carbon": 1.6}


def attenuation_per_mm(material: str, energy_kev: float = 60.0, *, density: float | None = None) -> float:
    """Linear attenuation coefficient μ (1/mm) of ``material`` at ``energy_kev`` (30–100 keV).

    ``density`` (g/cm³) defaults to :data:`DENSITY_G_CM3`; plastics and foams can be modelled as
    ``"water"`` with their own density (μ/ρ of PMMA, PU or PC is within ~10 % of water's here).
    """
    if material not in MASS_ATTENUATION_CM2_G:
        raise ValueError(f"material: expected one of {sorted(MASS_ATTENUATION_CM2_G)}, got {material!r}")
    e = positive(energy_kev, "energy_kev")
    if not _E_KEV[0] <= e <= _E_KEV[-1]:
        raise ValueError(f"energy_kev: tabulated for 30–100 keV, got {energy_kev}")
    tab = np.log(np.asarray(MASS_ATTENUATION_CM2_G[material]))
    if material == "lead" and e > 80.0:
        raise ValueError("energy_kev: lead's K edge (88 keV) lies in 80–100 keV; use <= 80 keV")
    mu_rho = float(np.exp(np.interp(np.log(e), np.log(_E_KEV), tab)))
    rho = DENSITY_G_CM3[material] if density is None else positive(density, "density")
    return mu_rho * rho / 10.0  # cm^-1 -> mm^-1

