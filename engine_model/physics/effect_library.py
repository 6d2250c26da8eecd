"""The library of optional physical effects (the hooks: :mod:`engine_model.physics.effect_base`).

Every effect is off by default: at its parameters' defaults it leaves every output unchanged.
``hyprog effects`` lists them with their parameters, units, realistic sizes and signatures.
Each parameter also has a documented *valid* range (``Param.valid``), wider than the realistic
one: bleed at most 10 % of W25 (+-2 % per 10,000 ft), HP off-take at most 1 MW, Reynolds
exponent 0-0.5 and flow ratio 0-2, intake losses up to 10 %, nozzle areas within +-20 %, a
sensor gain within +-50 %, a gain drift within +-1 % per cycle, time constants 0-30 s (spool)
and 0-3600 s (thermal). A value outside it is refused with the effect and parameter named
before a model variant is compiled.

==================  =====================================================================
effect              physics
==================  =====================================================================
customer_bleed      air taken from the HPC exit for the aircraft (cabin, anti-ice):
                    ``W = (f0 + f_alt max(alt, 0)/10,000 ft) W25``; typical airliner ECS demand is
                    1-2 % of core flow at cruise (Walsh & Fletcher, *Gas Turbine
                    Performance*, 2nd ed., ch. 5).
hp_offtake          shaft power taken from the HP spool by the accessory gearbox
                    (generators, hydraulic pumps), ``P`` [kW]; 100-250 kW for a twin of
                    this class.
reynolds            Reynolds-number effect on the turbomachinery at altitude. The Reynolds number
                    index of a component, ``RNI = (P_in/P_in_des) (T_in/T_in_des)^-1.2`` (Re ~ rho U
                    L / mu with U ~ sqrt(T) at constant corrected speed and mu ~ T^0.7), scales the
                    loss: ``(1 - eta) = (1 - eta_RNI=1) RNI^-n`` (Wassell, ASME J. Eng. Power 90,
                    1968; Walsh & Fletcher ch. 4 give n = 0.1-0.2; the library's ``typical`` size,
                    0.05, is a deliberately small one for detection studies, not a sourced value).
                    The efficiency modifier changes by ``-(1/eta_des - 1)(RNI^-n - 1)`` and the flow
                    modifier by ``flow_ratio`` times that.
duct_loss           changes of the duct total-pressure losses at their design flow, added to
                    the design's dP/P (bypass duct 1.0 %, booster-HPC duct 1.5 %, burner
                    4.0 %, each scaled with its corrected flow squared): ``d_bypass``,
                    ``d_icd``, ``d_burner``. A design-point quantity of a performance model
                    that a real engine's data may not share; the valid ranges, class-typical
                    choices rather than one source's, keep each loss between a fifth (bypass),
                    a third (transition duct) or a half (burner) of its design value and two
                    to four times it.
cooling_flow        changes of the turbine coolant flows bled from the HPC, as fractions of
                    its inlet flow added to the design's (HPT ``W31/W25`` 0.111, LPT
                    ``W32/W25`` 0.067): ``d_hpt``, ``d_lpt``. The HPT coolant bypasses the
                    burner, so the same work needs a hotter burner exit.
inlet_loss          an extra intake total-pressure loss (damage, ice, a poor intake lip):
                    ``P2 <- P2 (1 - dp - dp_ram Mach^2)``.
nozzle_area         a change of the core (``dA8``) and bypass (``dA18``) nozzle throat areas,
                    fractions (erosion, a mis-rigged variable nozzle, a trim).
map_scaling         map adaptation of one component (option ``component``: fan, LPC, HPC,
                    HPT, LPT): its efficiency and flow scalers vary with its corrected speed,
                    ``d_eff = eff_1 dn + eff_2 dn^2`` and ``d_flow = flow_1 dn + flow_2 dn^2``
                    with ``dn = n_corr - 1`` (``n_corr``: corrected speed relative to the SLS
                    design point), added to the component's modifiers. A generic map scaled
                    to the design point is right there and drifts away from the real
                    component's towards part power; performance engineers correct it with
                    scaling factors that depend on the operating point ("modification
                    factors", Stamatis, Mathioudakis & Papailiou, ASME J. Eng. Gas Turbines
                    Power 112, 1990; scaling factors along the operating line, Li & Pilidis,
                    2010; Kurzke, ASME GT2011 on which shapes a map can physically take;
                    polynomial map tuning, Tsoutsanis et al., Applied Energy 135, 2014). The
                    constant term is left out: at the design speed the scaler is theta itself
                    (the health parameter), so the effect is the shape, not the level.
map_slope           the slope of one compressor's speed lines (option ``component``: fan,
                    LPC, HPC): the slope ``kappa`` of its map's work line, ``psi / psi_des =
                    1 - kappa (phi - 1)`` along a speed line (:mod:`engine_model.physics.
                    maps`), scaled by ``1 + slope``. The isentropic head (hence the pressure
                    ratio) and the work change together, the efficiency does not. A flatter
                    line (``slope < 0``) holds the pressure ratio as the working point moves
                    along the speed line, e.g. when the bypass nozzle chokes between take-off
                    and cruise at the same corrected fan speed. The generic map's slope is a
                    class-typical value (``DesignSpec.fan_map``); the real blading's, set by
                    its exit metal angles and stage matching (Cumpsty, *Compressor
                    Aerodynamics*, ch. 4; Dixon & Hall, ch. 5), is what the adaptation to a
                    real engine estimates (the speed-line shape of map scaling: Kurzke,
                    ASME GT2011). At the design flow coefficient (SLS full power) nothing
                    moves.
map_pressure_ratio  the pressure-ratio scaler of one compressor's map (option
                    ``component``: fan, LPC, HPC), the third classic map scaler beside flow
                    and efficiency (Kurzke, ASME 96-GT-164; C-MAPSS's ``<c>_PR_mod``):
                    the isentropic head of every map point, and the work with it at the
                    map's efficiency, times ``1 + d_pr``, ``d_pr = pr_0 + pr_1 dn + pr_2
                    dn^2`` (:func:`engine_model.physics.components.compressor`). Unlike
                    the efficiency and flow scalers it has no health parameter beside it,
                    so its level ``pr_0`` is part of the effect. At the held corrected fan
                    speed a lower fan head gives less pressure (``P15``, ``P30`` down) for
                    less work (``Wf``, ``T50`` down).
design_scaling      the constant part of a component's map adaptation (option ``component``):
                    efficiency and flow scalers added to its health modifiers. On one engine
                    it is indistinguishable from theta; over a fleet it is the level every
                    engine shares (a model-engine mismatch), while theta is each engine's own
                    (:mod:`calibration.adaptation` fits the two apart). Not a candidate of the
                    discrepancy loop, whose theta per cycle would absorb it entirely.
sensor_bias         a sensor offset and gain on one channel: ``x <- x (1 + gain) + offset``.
sensor_drift        a sensor whose gain drifts with use: ``x <- x (1 + rate cycle)``; the
                    flight ``cycle`` is a per-row context parameter.
dynamics            (series) spool and thermal dynamics that the steady model lacks: the
                    spool speeds, pressures and flows lag the steady state with the rotor
                    time constant ``tau_spool`` and the temperatures with the heat-soak time
                    constant ``tau_thermal`` (first-order lags integrated exactly for an
                    input linear between samples).
==================  =====================================================================

Signatures
----------
``signature`` on each class is the documented sign of the change of key channels at the
effect's realistic (``typical``) size at two points, ``SLS`` (sea-level static, ISA, TRA
100) and ``CRZ`` (35,000 ft, Mach 0.8, TRA 80, ISA), at fixed TRA (the controller holds the
corrected fan speed, so ``Nf`` does not move for the steady effects). The reasoning:

- customer bleed / HP off-take: the HP turbine must drive the compressor while part of its
  air (or power) leaves, so the burner runs hotter: ``Wf``, ``T40``, ``T48``, ``T50`` rise.
- reynolds: only at altitude (RNI < 1) the components lose efficiency; at SLS nothing moves
  (RNI = 1); at cruise the hot section runs hotter (``T48``, ``Wf`` up).
- inlet_loss: ``P2`` falls, so every pressure downstream falls with it.
- duct_loss (every loss larger, at the held fan speed): the bypass duct's loss lowers ``P15``
  and pushes the fan up its speed line (more pressure ratio and work: the LPT needs a hotter
  gas, ``Wf`` and ``T50`` up); the burner's loss makes the HPC deliver more pressure for the
  same turbine inlet pressure (``P30`` up).
- cooling_flow (more coolant): less air passes the burner, which must run hotter for the same
  work (``T40``, ``T50``, ``Wf`` up), and the HPT's flow capacity, fed with less gas, holds a
  lower ``P30``.
- nozzle_area (a larger core nozzle): the LPT expands further, ``P50`` falls; ``T50`` falls.
- map_scaling: at SLS full power the component runs at its design corrected speed (dn = 0)
  and nothing moves; at cruise (TRA 80, dn < 0) a positive ``eff_1`` lowers the component's
  efficiency, so the burner runs hotter (``T48``, ``T50``, ``Wf`` up) for the HPC (the
  HPT's shape moves every channel by less than 0.1 % at both points and the LPT's nothing
  at cruise, so neither has a signature; the instance's ``moves`` and ``signature`` are per
  component).
- map_slope: at SLS full power the compressor runs at its design flow coefficient and nothing
  moves; at cruise the fan runs nearer choke (choked bypass nozzle, larger flow coefficient),
  where a flatter line keeps more pressure ratio (``P15``, ``P30`` up) and the core runs
  hotter for the larger work (``Wf``, ``T50`` up); the booster runs at a lower flow
  coefficient, where a flatter line gives less pressure rise (``P24``, ``T24`` down).
- map_pressure_ratio: at the held corrected fan speed a fan map with 1 % less head gives
  less pressure (``P15``, ``P30`` down) for less work (``Wf``, ``T50`` down); a booster's
  lower head lowers ``P24`` and ``T24``; the HPC's pressure ratio is held by the turbines'
  flow capacities, so its lower head is made up by a faster core (``Nc`` up).
- design_scaling: a lower efficiency or flow of a component (both at -1 %) at both points:
  for the booster, HPC, HPT and LPT the burner must run hotter (``Wf``, ``T50`` up); a less
  efficient fan raises less pressure at the held fan speed (``P15``, ``P30`` down) and the
  core, fed at a lower pressure, burns less (``Wf``, ``T50`` down); the signs per component
  are the instance's ``signature``.
- sensor_bias / sensor_drift: only the chosen channel moves; every other output is unchanged.
"""

from __future__ import annotations

import numpy as np

from engine_model.channels import OUTPUT_NAMES
from engine_model.validation import ENVELOPE

from .effect_base import Effect, EffectSpecError, Param, register

COMPONENT_MODS = ("fan", "LPC", "HPC", "HPT", "LPT")


@register
class CustomerBleed(Effect):
    name = "customer_bleed"
    description = ("Customer (aircraft) bleed from the HPC exit, a fraction of HPC inlet flow "
                   "that may follow a schedule in altitude above sea level.")
    params = (
        Param("f0", "-", 0.0, "bleed fraction of W25 at sea level", 0.015, (0.0, 0.04),
              valid=(0.0, 0.10)),
        Param("f_alt", "1/(10,000 ft)", 0.0, "change of the fraction per 10,000 ft", 0.002,
              (-0.005, 0.005), valid=(-0.02, 0.02)),
    )
    moves = ("Wf", "T24", "T30", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40", "P50")
    signature = {"SLS": {"Wf": +1, "T40": +1, "T48": +1, "T50": +1},
                 "CRZ": {"Wf": +1, "T40": +1, "T48": +1, "T50": +1}}

    def __init__(self, **values):
        """The fraction is ``f0 + f_alt max(alt, 0) / 10,000 ft``: the schedule is one of
        altitude above sea level, and below it (the envelope starts at -1,500 ft) the
        sea-level fraction holds, as an aircraft's bleed schedule is written. So the fraction
        is linear between sea level and the ceiling, and a specification whose fraction is
        negative at either end (so somewhere in the envelope) is refused. The model stays
        smooth in ``f0``, ``f_alt`` (the parameters a fit moves): a fit bounds ``f0`` at 0,
        and its result is checked here when loaded."""
        super().__init__(**values)
        top = ENVELOPE.alt_ft[1] / 1.0e4
        worst = min(self.values["f0"], self.values["f0"] + self.values["f_alt"] * top)
        if worst < 0.0:  # a negative bleed would add air to the engine
            raise EffectSpecError(
                f"effect {self.name}: the bleed fraction f0 + f_alt alt/10,000 ft is "
                f"{worst:.4g} < 0 between sea level and {ENVELOPE.alt_ft[1]:g} ft")

    def apply(self, hook, value, p, ctx):
        if hook != "W_customer_bleed":
            return value
        alt = ctx["w"][0]
        alt = 0.5 * (alt + abs(alt))  # max(alt, 0): the schedule starts at sea level
        return value + (p["f0"] + p["f_alt"] * alt / 1.0e4) * ctx["W25"]


@register
class HPOfftake(Effect):
    name = "hp_offtake"
    description = "Shaft power taken from the HP spool by the accessory gearbox."
    params = (Param("P_kw", "kW", 0.0, "HP shaft power extraction", 150.0, (0.0, 400.0),
                    valid=(0.0, 1000.0)),)
    moves = ("Wf", "Nc", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40")
    signature = {"SLS": {"Wf": +1, "T40": +1, "T48": +1, "T50": +1},
                 "CRZ": {"Wf": +1, "T40": +1, "T48": +1, "T50": +1}}

    def apply(self, hook, value, p, ctx):
        if hook != "P_offtake_HP":
            return value
        return value + 1.0e3 * p["P_kw"]


@register
class Reynolds(Effect):
    name = "reynolds"
    description = ("Reynolds-number index effect on the efficiency and flow capacity of the "
                   "fan, LPC, HPC, HPT and LPT (losses grow at altitude).")
    params = (
        Param("n", "-", 0.0, "loss exponent: (1 - eta) ~ RNI^-n", 0.05, (0.0, 0.2),
              valid=(0.0, 0.5)),
        Param("flow_ratio", "-", 0.5, "flow-capacity change / efficiency change", 0.5,
              (0.0, 1.0), valid=(0.0, 2.0)),
    )
    moves = ("Wf", "Nc", "T24", "T30", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40")
    signature = {"SLS": {"Wf": 0, "T48": 0, "T50": 0, "Nc": 0},
                 "CRZ": {"Wf": +1, "T40": +1, "T48": +1}}
    shape_params = ("flow_ratio",)  # with n = 0 nothing changes, whatever the ratio

    @staticmethod
    def rni(T_in, P_in, T_in_des, P_in_des):
        """Reynolds number index of a component inlet relative to its design point."""
        return (P_in / P_in_des) * (T_in / T_in_des) ** -1.2

    def apply(self, hook, value, p, ctx):
        comp, _, kind = hook.partition("_")
        if comp not in COMPONENT_MODS or kind not in ("eff_mod", "flow_mod"):
            return value
        rni = self.rni(ctx["T_in"], ctx["P_in"], ctx["T_in_des"], ctx["P_in_des"])
        d_eff = -(1.0 / ctx["eta_des"] - 1.0) * (rni ** (-p["n"]) - 1.0)
        return value + (d_eff if kind == "eff_mod" else p["flow_ratio"] * d_eff)


@register
class InletLoss(Effect):
    name = "inlet_loss"
    description = "Extra intake total-pressure loss, constant plus a ram part ~ Mach^2."
    params = (
        Param("dp", "-", 0.0, "fractional loss of P2 at Mach 0", 0.005, (0.0, 0.02),
              valid=(0.0, 0.10)),
        Param("dp_ram", "-", 0.0, "additional fractional loss per Mach^2", 0.005, (0.0, 0.02),
              valid=(0.0, 0.10)),
    )
    moves = ("Wf", "T40", "T48", "T50", "P15", "P2", "P21", "P24", "Ps30", "P30", "P40", "P50")
    signature = {"SLS": {"P2": -1, "P21": -1, "P30": -1, "P50": -1},
                 "CRZ": {"P2": -1, "P21": -1, "P30": -1, "P50": -1}}

    def apply(self, hook, value, p, ctx):
        if hook != "P2":
            return value
        mach = ctx["w"][1]
        return value * (1.0 - p["dp"] - p["dp_ram"] * mach**2)


@register
class NozzleArea(Effect):
    name = "nozzle_area"
    description = "Change of the core (A8) and bypass (A18) nozzle throat areas."
    params = (
        Param("dA8", "-", 0.0, "fractional change of the core nozzle throat area", 0.02,
              (-0.05, 0.05), valid=(-0.2, 0.2)),
        Param("dA18", "-", 0.0, "fractional change of the bypass nozzle throat area", 0.0,
              (-0.05, 0.05), valid=(-0.2, 0.2)),
    )
    moves = ("Wf", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40", "P50")
    signature = {"SLS": {"P50": -1, "T50": -1}, "CRZ": {"P50": -1, "T50": -1}}

    def apply(self, hook, value, p, ctx):
        if hook == "A8":
            return value * (1.0 + p["dA8"])
        if hook == "A18":
            return value * (1.0 + p["dA18"])
        return value


class DesignChange(Effect):
    """Base of the effects that add a parameter to a design quantity of the cycle: ``ADDS_TO``
    maps each hook (the quantity's name) to the parameter added to it."""

    ADDS_TO: dict = {}

    def apply(self, hook, value, p, ctx):
        q = self.ADDS_TO.get(hook)
        return value if q is None else value + p[q]


@register
class DuctLoss(DesignChange):
    name = "duct_loss"
    description = ("Changes of the total-pressure losses of the bypass duct, the booster-HPC "
                   "transition duct and the burner, at their design flow.")
    params = (
        Param("d_bypass", "-", 0.0, "change of the bypass duct's dP/P at design flow", 0.005,
              (-0.005, 0.01), valid=(-0.008, 0.03)),
        Param("d_icd", "-", 0.0, "change of the transition duct's dP/P at design flow", 0.005,
              (-0.005, 0.01), valid=(-0.010, 0.025)),
        Param("d_burner", "-", 0.0, "change of the burner's dP/P at design flow", 0.01,
              (-0.01, 0.02), valid=(-0.02, 0.04)),
    )
    moves = ("Wf", "Nc", "T24", "T30", "T40", "T48", "T50", "P15", "P21", "P24", "Ps30", "P30",
             "P40", "P50")
    signature = {"SLS": {"Wf": +1, "T50": +1, "P30": +1, "P15": -1},
                 "CRZ": {"Wf": +1, "T50": +1, "P30": +1, "P15": -1}}

    #: the design quantity each parameter is added to (:class:`DesignChange`)
    ADDS_TO = {"dp_bypass": "d_bypass", "dp_icd": "d_icd", "dp_burner": "d_burner"}


@register
class CoolingFlow(DesignChange):
    name = "cooling_flow"
    description = ("Changes of the turbine coolant flows taken from the HPC, as fractions of "
                   "the HPC inlet flow: HPT (W31) and LPT (W32).")
    params = (
        Param("d_hpt", "-", 0.0, "change of the HPT coolant fraction W31/W25", 0.01,
              (-0.02, 0.02), valid=(-0.05, 0.05)),
        Param("d_lpt", "-", 0.0, "change of the LPT coolant fraction W32/W25", 0.005,
              (-0.01, 0.01), valid=(-0.03, 0.03)),
    )
    moves = ("Wf", "Nc", "T24", "T30", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40")
    signature = {"SLS": {"Wf": +1, "T40": +1, "T50": +1, "P30": -1},
                 "CRZ": {"Wf": +1, "T40": +1, "T50": +1, "P30": -1}}

    ADDS_TO = {"f31": "d_hpt", "f32": "d_lpt"}


class ComponentEffect(Effect):
    """Base of the effects on one component's map (option ``component``): an instance is
    named ``<effect>_<component>`` and moves the channels ``MOVES[component]``, with the
    signs ``SIGNS[component]`` at the points of ``SIGNED_AT`` (the others: none declared);
    the allowed components are ``MOVES``'s keys. Subclasses set ``name``, ``description``,
    ``params``, ``MOVES``, ``SIGNS``, ``SIGNED_AT``, ``EXAMPLE`` (a component and parameters
    for the error message's example) and ``apply``."""

    options = ("component",)
    MOVES: dict = {}
    SIGNS: dict = {}
    SIGNED_AT: tuple = ("CRZ",)
    EXAMPLE = ""

    def __init__(self, **values):
        super().__init__(**values)
        comp = _required_option(self, "component", tuple(self.MOVES), self.EXAMPLE)
        self.component = comp
        self.name = f"{self.registry_name}_{comp}"
        self.moves = self.MOVES[comp]
        self.signature = {point: dict(self.SIGNS[comp]) if point in self.SIGNED_AT else {}
                          for point in ("SLS", "CRZ")}


@register
class MapScaling(ComponentEffect):
    name = "map_scaling"
    description = ("Map adaptation of one component (option component): efficiency and flow "
                   "scalers that vary with its corrected speed, d = c1 (n_corr - 1) + "
                   "c2 (n_corr - 1)^2.")
    params = (
        Param("eff_1", "-", 0.0, "efficiency scaler per unit of (n_corr - 1)", 0.05,
              (-0.2, 0.2), valid=(-1.0, 1.0)),
        Param("eff_2", "-", 0.0, "efficiency scaler per unit of (n_corr - 1)^2", 0.2,
              (-1.0, 1.0), valid=(-5.0, 5.0)),
        Param("flow_1", "-", 0.0, "flow scaler per unit of (n_corr - 1)", 0.05, (-0.2, 0.2),
              valid=(-1.0, 1.0)),
        Param("flow_2", "-", 0.0, "flow scaler per unit of (n_corr - 1)^2", 0.2, (-1.0, 1.0),
              valid=(-5.0, 5.0)),
    )
    # every parameter at its typical size: the measured channels that move by more than
    # 0.1 % at CRZ (n_corr below 1; tests/test_effects.py checks them) and the signs at CRZ.
    # The LPT runs at nearly its design corrected speed at CRZ (T49 falls with T2), so it
    # moves nothing there; its shape shows at part power.
    MOVES = {
        "fan": ("Wf", "T48", "P15", "P21", "Ps30", "P30", "P40", "P50"),
        "LPC": ("P24",),
        "HPC": ("Wf", "T30", "T40", "T48", "T50", "P24"),
        "HPT": (),
        "LPT": (),
    }
    SIGNS = {"fan": {"Wf": -1, "P15": -1, "P30": -1},
             "LPC": {"P24": -1, "T24": -1},
             "HPC": {"Wf": +1, "T30": +1, "T48": +1, "T50": +1},
             "HPT": {"Wf": +1, "T48": +1, "T50": +1},
             "LPT": {}}

    EXAMPLE = "HPC,eff_1=0.05"

    def apply(self, hook, value, p, ctx):
        if hook == f"{self.component}_eff_mod":
            dn = ctx["n_corr"] - 1.0
            return value + p["eff_1"] * dn + p["eff_2"] * dn * dn
        if hook == f"{self.component}_flow_mod":
            dn = ctx["n_corr"] - 1.0
            return value + p["flow_1"] * dn + p["flow_2"] * dn * dn
        return value


@register
class MapSlope(ComponentEffect):
    """The slope of a compressor's speed lines (option ``component``)."""

    name = "map_slope"
    description = ("Slope of one compressor's speed lines (option component: fan, LPC, HPC): "
                   "the work line's slope kappa scaled by 1 + slope.")
    params = (
        Param("slope", "-", 0.0, "fractional change of the work line's slope kappa", -0.3,
              (-0.5, 0.5), valid=(-0.8, 1.0)),
    )
    # slope at its typical size (-0.3): the measured channels that move by more than 0.1 % at
    # CRZ (tests/test_effects.py checks them) and the signs there; at SLS full power every
    # compressor runs at its design flow coefficient, where the slope changes nothing
    # (the HPC's stage-averaged flow coefficient stays near 1 at CRZ: it moves nothing there;
    # its slope shows further from the design point, at low power)
    MOVES = {
        "fan": ("Wf", "Nc", "T24", "T30", "T40", "T48", "T50", "P15", "P21", "P24", "Ps30",
                "P30", "P40", "P50"),
        "LPC": ("Nc", "T24", "T30", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40", "P50"),
        "HPC": (),
    }
    SIGNS = {"fan": {"Wf": +1, "P15": +1, "P30": +1, "T50": +1},
             "LPC": {"T24": -1, "P24": -1, "P30": -1},
             "HPC": {}}

    EXAMPLE = "fan,slope=-0.3"

    def apply(self, hook, value, p, ctx):
        if hook == f"{self.component}_slope_mod":
            return value + p["slope"]
        return value


@register
class MapPressureRatio(ComponentEffect):
    """A compressor map's pressure-ratio scaler and its change with corrected speed
    (option ``component``)."""

    name = "map_pressure_ratio"
    description = ("Pressure-ratio scaling of one compressor's map (option component: fan, "
                   "LPC, HPC): d_pr = pr_0 + pr_1 dn + pr_2 dn^2, dn = n_corr - 1.")
    params = (
        Param("pr_0", "-", 0.0, "pressure-ratio (isentropic head) scaler at the design speed",
              -0.01, (-0.03, 0.03), valid=(-0.10, 0.10)),
        Param("pr_1", "-", 0.0, "pressure-ratio scaler per unit of (n_corr - 1)", 0.05,
              (-0.2, 0.2), valid=(-1.0, 1.0)),
        Param("pr_2", "-", 0.0, "pressure-ratio scaler per unit of (n_corr - 1)^2", 0.2,
              (-1.0, 1.0), valid=(-5.0, 5.0)),
    )
    # every parameter at its typical size: the measured channels that move by more than
    # 0.1 % at SLS or CRZ (tests/test_effects.py checks them) and the signs at both points.
    # The controller holds the corrected fan speed, so a fan giving 1 % less head raises
    # less pressure (P15, P30 down) and takes less work (Wf, T50 down). The HPC's pressure
    # ratio is set by the turbines' flow capacities: a lower head is made up by speed (Nc
    # up), and little else moves.
    MOVES = {
        "fan": ("Wf", "T40", "T48", "T50", "P15", "P21", "Ps30", "P30", "P40", "P50"),
        "LPC": ("P24",),
        "HPC": ("Nc",),
    }
    SIGNS = {"fan": {"Wf": -1, "P15": -1, "P30": -1, "T50": -1},
             "LPC": {"P24": -1, "T24": -1},
             "HPC": {"Nc": +1}}
    SIGNED_AT = ("SLS", "CRZ")

    EXAMPLE = "fan,pr_0=-0.01"

    def apply(self, hook, value, p, ctx):
        if hook == f"{self.component}_pr_mod":
            dn = ctx["n_corr"] - 1.0
            return value + p["pr_0"] + p["pr_1"] * dn + p["pr_2"] * dn * dn
        return value


@register
class DesignScaling(ComponentEffect):
    """The constant part of a component's map adaptation (option ``component``)."""

    name = "design_scaling"
    description = ("Design-point map scaling of one component (option component): constant "
                   "efficiency and flow scalers, the level that a fleet shares.")
    params = (
        Param("eff", "-", 0.0, "efficiency scaler (added to the efficiency modifier)", -0.01,
              (-0.03, 0.03), valid=(-0.15, 0.05)),
        Param("flow", "-", 0.0, "flow scaler (added to the flow modifier)", -0.01,
              (-0.03, 0.03), valid=(-0.15, 0.05)),
    )
    # both scalers at their typical size (-1 %): the measured channels that move by more than
    # 0.1 % at SLS or CRZ (tests/test_effects.py checks them) and the signs at both points
    MOVES = {
        "fan": ("Wf", "Nc", "T30", "T40", "T48", "T50", "P15", "P21", "P24", "Ps30", "P30",
                "P40", "P50"),
        "LPC": ("Wf", "Nc", "T24", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40"),
        "HPC": ("Wf", "T24", "T30", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40"),
        "HPT": ("Wf", "Nc", "T24", "T30", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40"),
        "LPT": ("Wf", "T40", "T48", "T50", "P24", "Ps30", "P30", "P40", "P50"),
    }
    SIGNS = {"fan": {"Wf": -1, "T50": -1, "P15": -1, "P30": -1},
             "LPC": {"Wf": +1, "T50": +1, "P30": -1, "Nc": +1},
             "HPC": {"Wf": +1, "T30": +1, "T50": +1, "P30": -1},
             "HPT": {"Wf": +1, "T50": +1, "P30": +1, "Nc": -1},
             "LPT": {"Wf": +1, "T50": +1, "P30": +1, "Nc": -1}}

    SIGNED_AT = ("SLS", "CRZ")
    EXAMPLE = "HPC,eff=-0.01"

    def apply(self, hook, value, p, ctx):
        if hook == f"{self.component}_eff_mod":
            return value + p["eff"]
        if hook == f"{self.component}_flow_mod":
            return value + p["flow"]
        return value


def _required_option(effect: Effect, key: str, allowed, example: str) -> str:
    """The effect's option ``key``, required and one of ``allowed`` (``example``: a value and
    what follows it in the message's example specification)."""
    name = effect.registry_name
    value = effect.opts.get(key)
    if value is None:
        raise EffectSpecError(f"effect {name}: option '{key}' is required (e.g. "
                              f"{name}:{key}={example})")
    if value not in allowed:
        raise EffectSpecError(f"effect {name}: unknown {key} {value!r}; one of "
                              f"{', '.join(allowed)}")
    return value


def _channel_option(effect: Effect) -> str:
    return _required_option(effect, "channel", OUTPUT_NAMES, "T48,...")


class SensorEffect(Effect):
    """Base of the effects on one sensor's reading (option ``channel``): the steady state is
    untouched and only the hooked reading ``sensor:<channel>`` is rewritten by
    :meth:`reading`; subclasses set ``name``, ``description``, ``params`` and ``reading``."""

    options = ("channel",)
    moves = ("<channel>",)
    signature = {"SLS": {"<channel>": +1, "<others>": 0}, "CRZ": {"<channel>": +1,
                                                                   "<others>": 0}}

    def __init__(self, **values):
        super().__init__(**values)
        self.channel = _channel_option(self)
        self.name = f"{self.registry_name}_{self.channel}"

    def apply(self, hook, value, p, ctx):
        if hook != "sensor:" + self.channel:
            return value
        return self.reading(value, p)

    def reading(self, value, p):
        """The reading as the faulty sensor reports the true ``value``."""
        raise TypeError(f"{type(self).__name__} must define reading()")


@register
class SensorBias(SensorEffect):
    """Offset and gain of one sensor. The gain's valid range is relative (|gain| <= 0.5); the
    offset is in the channel's own unit, whose scale differs by a factor 10^4 between
    channels (psia to rpm), so it has no valid range of its own. At one reading the two
    trade (``x g + b`` the same for every pair on a line): only readings far apart tell
    them apart, so a fitted offset is judged with its gain and against the channel's readings
    in the data (a gain of -24 % with an offset of a quarter of the reading is a knob)."""

    name = "sensor_bias"
    description = "Offset and gain error of one sensor: x <- x (1 + gain) + offset."
    params = (
        Param("offset", "channel unit", 0.0, "additive offset", None, None),
        Param("gain", "-", 0.0, "relative gain error", 0.005, (-0.02, 0.02),
              valid=(-0.5, 0.5)),
    )

    def reading(self, value, p):
        return value * (1.0 + p["gain"]) + p["offset"]


@register
class SensorDrift(SensorEffect):
    name = "sensor_drift"
    description = "A sensor gain that drifts with use: x <- x (1 + rate cycle)."
    params = (
        Param("rate", "1/cycle", 0.0, "relative gain change per flight cycle", 1e-4,
              (-5e-4, 5e-4), valid=(-1e-2, 1e-2)),
        Param("cycle", "cycle", 0.0, "flight cycle (context: supplied per row)", None, None,
              kind="context"),
    )

    def reading(self, value, p):
        return value * (1.0 + p["rate"] * p["cycle"])


# channels that follow the spools (speeds, pressures, flows) and the temperatures
_THERMAL = ("T24", "T30", "T40", "T48", "T50")


@register
class Dynamics(Effect):
    name = "dynamics"
    series = True
    description = ("Spool and thermal dynamics: speeds, pressures and flows lag the steady "
                   "state with the rotor time constant, temperatures with the heat-soak time "
                   "constant (applied to each flight's output series).")
    params = (
        Param("tau_spool", "s", 0.0, "rotor (spool) time constant", 1.5, (0.5, 4.0),
              valid=(0.0, 30.0)),
        Param("tau_thermal", "s", 0.0, "heat-soak time constant of the temperatures", 60.0,
              (10.0, 300.0), valid=(0.0, 3600.0)),
    )
    moves = ("Wf", "Nf", "Nc", "T24", "T30", "T40", "T48", "T50", "P15", "P21", "P24", "Ps30",
             "P30", "P40", "P50")
    signature = {"SLS": {}, "CRZ": {}}  # a steady point is its own steady state
    #: Outputs that do not follow the engine: the intake pressure (the flight condition)
    #: and the controller's demand (the throttle); every other output but the temperatures
    #: follows the spools (speeds, every station pressure, every flow, and what is computed
    #: from them), so that they lag together and stay consistent (P40 < P30 at every sample).
    #: ``Wf`` lags with them: the outputs are those of the steady point the spools are at, a
    #: simplification. A real controller leads the spools with its fuel command (acceleration
    #: and deceleration schedules, fuel first and speed after), which this effect does not model.
    NOT_LAGGED = ("P2", "PCNfR_dmd")

    @staticmethod
    def lag(y: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
        """First-order lag ``tau dy/dt = u - y`` of the columns of ``u = y`` (steady values)
        over times ``t`` [s], starting in equilibrium, integrated exactly for ``u`` linear
        between samples."""
        u = np.asarray(y, float)
        if tau <= 0.0 or len(u) < 2:
            return u.copy()
        dt = np.diff(np.asarray(t, float))
        a = np.exp(-dt / tau)
        # over one step, with u linear from u0 to u1: y1 = a y0 + b0 u0 + b1 u1
        b1 = 1.0 - tau / dt * (1.0 - a)
        b0 = tau / dt * (1.0 - a) - a
        if np.allclose(dt, dt[0]):  # uniform sampling: one linear filter per column
            from scipy.signal import lfilter, lfiltic

            num, den = [b1[0], b0[0]], [1.0, -a[0]]
            out = np.empty_like(u)
            for j in range(u.shape[1] if u.ndim == 2 else 1):
                col = u[:, j] if u.ndim == 2 else u
                zi = lfiltic(num, den, y=[col[0]], x=[col[0]])
                res = lfilter(num, den, col, zi=zi)[0]
                if u.ndim == 2:
                    out[:, j] = res
                else:
                    out[:] = res
            return out
        out = np.empty_like(u)
        out[0] = u[0]
        for k in range(1, len(u)):
            out[k] = a[k - 1] * out[k - 1] + b0[k - 1] * u[k - 1] + b1[k - 1] * u[k]
        return out

    def apply_series(self, df, values=None):
        """``df``: one flight's outputs with a ``t`` column [s]; returns the lagged copy."""
        v = {**self.values, **(values or {})}
        out = df.copy()
        t = df["t"].to_numpy(float)
        if np.any(np.diff(t) <= 0):
            raise ValueError("dynamics: the time column t must increase within a flight")
        thermal = [c for c in _THERMAL if c in df.columns]
        spool = [c for c in OUTPUT_NAMES
                 if c in df.columns and c not in thermal and c not in self.NOT_LAGGED]
        if spool:
            out[spool] = self.lag(df[spool].to_numpy(float), t, v["tau_spool"])
        if thermal:
            out[thermal] = self.lag(df[thermal].to_numpy(float), t, v["tau_thermal"])
        return out
