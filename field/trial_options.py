"""What a field trial is asked to do: :class:`TrialOptions` (the objective, the planner, the safety
limits, verification), checked when made; :mod:`field.trial` runs a trial with them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from field.link.messages import DEFAULT_MAX_PILE_AGE_S
from planner.constraints import Constraints
from planner.inference import PRODUCT_F3_BALANCE, Objective, f3_sigma_b
from planner.ranker import U_WEIGHT, check_u_weight
from planner.runtime import PRECISIONS


@dataclass(frozen=True)
class TrialOptions:
    objective: Literal["f1", "f2", "f3"] = "f3"
    f3_balance: Literal["network", "hang"] = PRODUCT_F3_BALANCE  # f3's b: the network's B map or the tilt the
    #                                                             load will hang with (planner.balance)
    f3_sigma_b: float | None = None  # f3's balance tolerance [cos beta]; None = the source's (0.05 hang, 0.25 network)
    model: str | None = None  # checkpoint; None = the shipped default
    views: int = 1  # dihedral views the planner averages (1, 2, 4, 8; planning time grows with it) [-]
    view_spread_k: float = 0.0  # U logit lowered by k x its spread over the views (needs views > 1) [-]
    precision: str = "auto"  # the network's number format (planner.runtime.PRECISIONS); "auto": int8 where the CPU
    #                          has int8 dot products and the model a calibration, else bf16 / fp32 (planner.runtime)
    rerank: bool = True  # the grasp ranker re-scores the network's best grasps (planner.ranker); False = U alone
    ranker: str | None = None  # ranker checkpoint; None = the shipped one
    rerank_k: int = 4  # grasps re-scored per objective (the best by f1 and by f3) [-]
    ranker_u_weight: float = U_WEIGHT  # U's share of the blend's logit with the ranker's p [-]
    clear_obstacles: bool = True  # no grasp whose claws' footprint covers an obstacle the re-render shows
    #                               (planner.constraints.Constraints.clear_obstacles); False: the operator's choice
    claw_plate_m: float = Constraints.claw_plate_m  # the footprint beyond each end of the opening [m] (the grapple's)
    claw_width_m: float = Constraints.claw_width_m  # the footprint across the closing axis [m] (the grapple's)
    allow_float: bool = False  # accept RTK float endpoints (the operator's explicit choice)
    max_pile_age_s: float = DEFAULT_MAX_PILE_AGE_S  # refuse plans on pile data older than this [s]
    crane_base_tm: tuple[float, float, float] | None = None  # SWEREF 99 TM E, N [m], ellipsoidal h [m]
    min_reach_m: float = 2.0  # [m]
    max_reach_m: float = 10.0  # [m]
    lift_capacity_kg: float | None = 1500.0  # [kg]; None = unchecked
    wood_density_kg_m3: float = 900.0  # [kg/m³]
    ack_timeout_s: float = 2.0  # [s]
    outcome_timeout_s: float = 120.0  # [s]
    verify_k: int = 8  # grasps the twin tries on the reconstruction before one is sent [-]; 0 = off
    verify_copies: int = 0  # perturbed copies of the reconstruction each is also tried on [-]
    verify_budget_s: float | None = 20.0  # wall time for the twin's trials [s]; None = no limit
    verify_workers: int = 0  # processes for them; 0 = all cores, 1 = in this process [-]
    verify_seed: int = 0  # seed of the perturbed copies [-]
    operator_rank: int | None = None  # plan rank (1 = best) to send when no grasp verified (or
    # verification is off): the operator's explicit choice [-]

    def __post_init__(self) -> None:
        if self.objective not in ("f1", "f2", "f3"):
            raise ValueError(f"objective must be f1, f2 or f3, got {self.objective!r}")
        self.objective_spec()  # a ValueError naming f3's balance or sigma_b
        if not self.max_pile_age_s > 0:
            raise ValueError("max_pile_age_s must be > 0")
        from planner.inference import check_views

        check_views(self.views, self.view_spread_k)
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {list(PRECISIONS)}, got {self.precision!r}")
        if self.ranker is not None and not self.rerank:
            raise ValueError("a ranker checkpoint is given but re-ranking is off")
        if isinstance(self.rerank_k, bool) or not isinstance(self.rerank_k, int) or self.rerank_k < 1:
            raise ValueError(f"rerank_k must be a whole number >= 1, got {self.rerank_k!r}")
        check_u_weight(self.ranker_u_weight)
        if not isinstance(self.clear_obstacles, bool):
            raise ValueError(f"clear_obstacles is a switch: must be True or False, got {self.clear_obstacles!r}")
        Constraints(claw_plate_m=self.claw_plate_m, claw_width_m=self.claw_width_m)  # a ValueError naming the field
        if not 0 <= self.min_reach_m < self.max_reach_m:
            raise ValueError("need 0 <= min_reach_m < max_reach_m")
        if isinstance(self.verify_k, bool) or not isinstance(self.verify_k, int) or self.verify_k < 0:
            raise ValueError(f"verify_k must be a whole number >= 0 (0 = no verification), got {self.verify_k!r}")
        if self.operator_rank is not None and (isinstance(self.operator_rank, bool) or self.operator_rank < 1):
            raise ValueError(f"operator_rank is a plan rank (1 = the best), got {self.operator_rank!r}")
        if self.verify_k:
            self.verify_config()  # its own checks: a budget too small for one trial, copies, workers

    def objective_spec(self) -> Objective:
        """The planning objective: its kind, with f3's balance source and tolerance."""
        return Objective(kind=self.objective, sigma_b=f3_sigma_b(self.f3_balance, self.f3_sigma_b),
                         balance=self.f3_balance)

    def verify_config(self, fits: tuple[str, ...] | list[str] = (), end_sigmas_m=None):
        """The :class:`planner.verify.VerifyConfig` of these options; ``fits``: how the
        reconstruction placed each log (its report's ``fit``) and ``end_sigmas_m`` its less certain
        end's sigma per log (:func:`reconstruct.report.log_end_sigmas`), for per-log perturbation sigmas."""
        from planner.pile_copies import PerturbationConfig, perturbation_for_fits
        from planner.verify import VerifyConfig

        pert = PerturbationConfig(copies=self.verify_copies, seed=self.verify_seed)
        if fits:
            pert = perturbation_for_fits(fits, pert, end_sigmas_m)
        return VerifyConfig(k=max(1, self.verify_k), time_budget_s=self.verify_budget_s, workers=self.verify_workers,
                            perturbation=pert)
