"""The main job (``loggrasp demo``) as a library function, and the crane twin it serves.

:func:`run_demo` wires the whole chain on the bundled recorded scan (:data:`DEMO_DATA`): a crane
controller twin is served in this process on the link (executing grasps in pybullet on the true
pile), then :func:`field.trial_record.run_trial_record` reconstructs the scan, plans, verifies in the
twin on the reconstruction, sends the SWEREF 99 TM grasp and records everything. The CLI command
only checks flags, prints and maps errors to exit codes.

:func:`default_crane_base` and :func:`crane_config` are the pieces ``crane-sim``, the demo and
the tests share; the crane twin is served by :func:`field.controller.controller_in_thread`.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from field.controller import ControllerConfig, ReachEnvelope, controller_in_thread
from field.trial import TrialOptions

#: The bundled recorded field scan: stereo pair, calibration, scan pose, RTK endpoint CSV and the
#: true pile the twin crane executes on.
DEMO_DATA = Path(__file__).resolve().parent / "demo_data"

CRANE_OFFSET_SOUTH_M = 5.0  # the twin crane's default base: this far south of the pile centre [m]
#: the bundled scan is old: its staleness limit is set this far past its age [s]
DEMO_AGE_MARGIN_S = 3600.0


def default_crane_base(pile) -> tuple[float, float, float]:
    """A crane base (E, N, H in SWEREF 99 TM + RH 2000 [m]) :data:`CRANE_OFFSET_SOUTH_M` south
    (site frame) of the pile centre, at ground height."""
    import numpy as np

    from synth.geometry.geodesy import pile_to_site, site_to_tm

    c = np.mean([log.centre_m for log in pile.logs], axis=0)
    site = pile_to_site(pile.georef, np.array([c[0], c[1], float(pile.terrain.height_at(c[0], c[1]))]))
    e, n, h = site_to_tm(pile.georef, site + np.array([0.0, -CRANE_OFFSET_SOUTH_M, 0.0]))
    return float(np.ravel(e)[0]), float(np.ravel(n)[0]), float(np.ravel(h)[0])


def crane_config(base_tm, max_reach_m: float, max_pile_age_s: float, journal: str | None = None, *,
                 no_journal: bool = False) -> ControllerConfig:
    """The controller's config for a crane at ``base_tm`` (E, N, H [m]); journal at ``journal``
    (None: the link's default file) unless ``no_journal`` opts out."""
    return ControllerConfig(reach=ReachEnvelope(base_easting_m=base_tm[0], base_northing_m=base_tm[1],
                                                base_height_m=base_tm[2], max_reach_m=max_reach_m),
                            max_pile_age_s=max_pile_age_s, journal_path=journal, no_journal=no_journal)


@dataclass(frozen=True)
class DemoSetup:
    """What the demo runs with, decided before anything is sent."""

    data: Path  # the recorded scan, survey and true pile (:data:`DEMO_DATA`)
    truth: object  # the true pile (synth.scene.pile.PileSpec) the crane twin executes on
    record_dir: Path  # the trial record (replaced)
    link_url: str  # the link, with the SecOC key
    key_path: Path  # the link's pre-shared key (made once)
    journal_path: Path  # the crane twin's command-id journal
    base_tm: tuple[float, float, float]  # crane base [m]
    scan_age_s: float  # how old the bundled scan is [s]
    max_pile_age_s: float  # the staleness limit, raised past that age [s]
    notes: list[str] = field(default_factory=list)  # what a person should be told
    signing_key_path: Path | None = None  # the crane twin's signing key (its public key: + .pub; made once)


def prepare_demo(out_dir: str | Path, link_url: str, data: Path = DEMO_DATA) -> DemoSetup:
    """Key, journal and staleness limit for a demo into ``out_dir``; the old record is removed."""
    from field.link.link_config import keyed_url
    from field.link.secoc import generate_key_file
    from field.link.signing import generate_signing_key
    from field.trial import captured_time
    from synth.scene.pile import read_pile

    out = Path(out_dir)
    age = time.time() - captured_time(data / "scan", data / "gnss.csv")
    max_age = age + DEMO_AGE_MARGIN_S
    record = out / "trial"
    if record.exists():
        shutil.rmtree(record)
    key, sign = out / "link.key", out / "crane.sign"
    if not key.exists():
        generate_key_file(key)
    if not sign.exists():
        generate_signing_key(sign)
    journal = out / "crane-journal.jsonl"
    link = keyed_url(link_url, str(key), str(sign))  # the twin crane and the laptop share the URL
    notes = [f"bundled scan recorded {age / 86400:.1f} days ago: staleness limit raised to {max_age:.0f} s "
             "for the demo",
             f"authenticated frames on (SecOC-style MACs, key {key}; the crane's answers signed, key {sign}); "
             f"crane journal {journal}"]
    truth = read_pile(data / "truth" / "pile.json")
    return DemoSetup(data, truth, record, link, key, journal, default_crane_base(truth), age, max_age, notes,
                     signing_key_path=sign)


def demo_options(setup: DemoSetup, model: str | Path | None, verify: bool = True, rerank: bool = True) -> TrialOptions:
    """The field trial's options in the demo: objective f3, the crane's default reach, verification
    on unless ``verify`` is False, the shipped grasp ranker unless ``rerank`` is False."""
    reach = ReachEnvelope().max_reach_m
    return TrialOptions(objective="f3", model=None if model is None else str(model), allow_float=False,
                        max_pile_age_s=setup.max_pile_age_s, crane_base_tm=setup.base_tm, max_reach_m=reach,
                        rerank=rerank, **({} if verify else {"verify_k": 0}))


def run_demo(setup: DemoSetup, options: TrialOptions, confirm: Callable | None = None,
             progress: Callable[[str], None] | None = None, foxglove_port: int | None = None) -> dict:
    """The whole chain on the bundled scan, against a crane twin served here on the true pile;
    the trial record (also written to ``setup.record_dir``, with its ``trial.mcap``; served live
    on 127.0.0.1:``foxglove_port`` when given). A trial stopped before sending raises
    :class:`field.trial.TrialAborted` with its record written."""
    from field.executor import PybulletTrialExecutor
    from field.trial_record import run_trial_record

    config = crane_config(setup.base_tm, options.max_reach_m, setup.max_pile_age_s, str(setup.journal_path))
    with controller_in_thread(setup.link_url, PybulletTrialExecutor(setup.truth), config):
        return run_trial_record(setup.data / "scan", setup.data / "gnss.csv", setup.link_url, setup.record_dir,
                                options, confirm=confirm, progress=progress, foxglove_port=foxglove_port)
