"""The one engine model shared by the simulator (core.plant) and the monitor (core.monitor).

    engine.py        EngineSpec: geometry, masses, shaft line, friction parameters, combustion, sensors; TOML presets
                     in engines/*.toml
    kinematics.py    slider-crank kinematics and J(theta) (physics.md §1, §3)
    terms.py         the loss-term library: LossTerm, TermLibrary (composable), the six Rezeka-Henein terms
    effects/         the effect library: Effect objects (plant hooks, monitor terms), parse_effect
    chain.py         the drive train (torsional chain of inertias, shafts, dampers): one model for both sides
    dynamics.py      the monitor's view of the chain: receptance, dissipation, static twist, rigid balance
    torques.py       gas, reciprocating-mass and load torques (physics.md §2, §3, §5)
    indicated.py     net indicated work, IMEP, peak pressure from a pressure trace
    thermo.py        single-zone cylinder model (the simulator's combustion)
    engine_model.py  EngineModel = spec + term library + coefficients + effects, TOML in and out

    model = EngineModel.from_spec(load_engine("k9k-4cyl")).with_term(auxiliaries_quadratic(), 0.0)
    EngineModel.from_toml(model.to_toml()) == model
"""

from frictionwatch.core.model.chain import DriveTrain, drive_train
from frictionwatch.core.model.effects import EFFECTS, Effect, auxiliaries_quadratic, parse_effect, resolve_effects
from frictionwatch.core.model.engine import EngineSpec, SpecError, available_presets, load_engine, spec_from_toml_text
from frictionwatch.core.model.engine_model import EngineModel, as_model, known_terms, load_model
from frictionwatch.core.model.terms import LossTerm, TermLibrary, cylinder_samples, loss_kernel, rezeka_henein

__all__ = ["EFFECTS", "DriveTrain", "Effect", "EngineModel", "EngineSpec", "LossTerm", "SpecError", "TermLibrary",
           "as_model", "auxiliaries_quadratic", "available_presets", "cylinder_samples", "drive_train", "known_terms",
           "load_engine", "load_model", "loss_kernel", "parse_effect", "resolve_effects", "rezeka_henein", "spec_from_toml_text"]
