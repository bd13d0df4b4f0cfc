"""The joint estimator's parameters (issue 37, step 2): :class:`JointConfig`, every number a named field with
its unit and the reason for its value, and the estimator ids a reconstruction records.

The joint estimator (:mod:`reconstruct.fitting.joint_match`, :mod:`reconstruct.fitting.joint_ends`) replaces
revision 22's matching and end rules by likelihoods: each survey point is a Gaussian (its receiver's accuracy)
mixed with an outlier component, the scan along a log's axis a per-bin likelihood, the matching one assignment
with explicit costs for hidden and missed logs. It is selected by ``ReconstructConfig.estimator = "joint"``;
revision 22 (``"rules22"``) stays the default until the joint one matches or beats it on the held-out set.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

#: the estimators ``ReconstructConfig.estimator`` selects
ESTIMATORS = ("rules22", "joint")
#: raised whenever a change to the joint estimator makes different piles from the same scan (recorded in the
#: report as ``estimator_revision`` and in bench keys)
JOINT_REVISION = 20


@dataclass(frozen=True)
class JointConfig:
    """Parameters of the joint estimator (units in the names; each comment says why this value)."""

    # -- survey points: a Gaussian per point (its receiver's accuracy) mixed with an outlier component --
    outlier_prior: float = 0.05  # prior share of survey points that are wrong (a swapped id, a point taken
    #                              off the end): field crews report a few in a hundred [-]
    outlier_spread_m: float = 1.0  # the outlier component is uniform over a cube this wide around the log end
    #                                (a wrong point lies anywhere near the pile) [m]
    outlier_flag_prob: float = 0.5  # a point whose posterior outlier probability exceeds this is flagged
    #                                 (named in contradicted_points) and does not place its end [-]
    pose_sigma_m: float = 0.01  # what the registered scan pose adds to every point's sigma (the registration
    #                             brings the scan onto the points: its residual error ~1 cm on twin scans) [m]
    top_smear_m: float = 0.01  # stereo shows a log's top this far past its end (the end face's smear; fitting
    #                            revision 6 measured +9 mm on twin scans): the scan's evidence is moved back [m]
    axis_lateral_sigma_m: float = 0.01  # a scan-fitted axis across, near the seen part (the cylinder fit's
    #                                     RMS ~5 mm over hundreds of points, plus stereo smear) [m]
    # -- the scan along the axis: per-bin likelihoods of what a bin shows, inside the log vs past its end --
    p_on_inside: float = 0.80  # a bin inside the log shows its top (the rest: something over it, or unseen) [-]
    p_below_inside: float = 0.08  # ... or the scan sees below its top there (gaps between crossing logs over it,
    #                               a log sagging under its straight fit: at 0.02 a few such bins threw out
    #                               correct fixed points far past them) [-]
    p_on_outside: float = 0.30  # a bin past the end shows a surface at the top's height: in a pile the next log
    #                             in line, a crossing log's flank, an obstacle (at 0.04 a neighbour's top 20-50 cm
    #                             on outweighed correct fixed points) [-]
    p_below_outside: float = 0.55  # ... or the scan sees below where the top would be (ground, lower logs) [-]
    p_over_inside: float = 0.10  # a bin shows something over the top: another log across this one, inside it ...
    p_over_outside: float = 0.10  # ... as often as a log across the ground past its end (piles cross): no
    #                               evidence either way (taken as the rest: otherwise an end
    #                               falls short of a stretch under a crossing log) [-]
    contiguity: bool = False  # what a bin shows is a Markov chain inside the log and another past its end, not
    #                           independent bins (joint_ends.edge_log_likelihood), so a neighbour's top in line
    #                           past a gap counts once, not once per 2 cm bin. Off: on the first 21 tuning
    #                           scans it moved 8 of 63 worst ends by over 2 cm, 7 for the worse (a log seen in
    #                           part, its extrapolated top over a run of 'below' bins, lost a correct fixed
    #                           end); docs/reconstruction.md, joint revisions 9-10
    run_on_inside_m: float = 0.5  # a log's top, once seen, goes on this far on average before a bin shows
    #                               something else (logs are 1-4 m long; stereo drops a few bins) [m]
    run_below_inside_m: float = 0.02  # a bin under a log's top (a sag, a gap between logs across it) is
    #                                   rarely followed by another: a bin's width (no run) [m]
    run_over_inside_m: float = 0.10  # a log across this one hides its top over about its own width [m]
    run_outside_m: float = 0.10  # past an end, the ground or a log across go on this far on average (tens of
    #                              centimetres, smeared over a few bins by stereo) [m]
    run_on_outside_m: float = 0.04  # ... and a surface at the top's height past the end (a neighbour's flank
    #                                 or top) this far: the longer, the more cheaply a neighbour abutting
    #                                 explains a log's own last stretch (a seen end with the ground past it is
    #                                 sure to ~4.5 cm along at 0.04 m; with p_on_outside 0.1 it would be 2.3 cm
    #                                 but the end would go onto a neighbour in line past a 6 cm gap) [m]
    end_prior_sigma_m: float = 1.0  # the cylinder fit's end as a weak prior where nothing else says: a fit on a
    #                                 log seen in part stops where its points do, so no surer than a log's half
    #                                 length (at 0.3 m an end fell 40 cm short of an
    #                                 unseen stretch its float point lay in) [m]
    search_m: float = 0.8  # each end's posterior is evaluated this far either side of its prior [m]
    min_end_sigma_m: float = 0.01  # an end is never surer than this (2 cm bins, stereo smear) [m]
    # -- the matching: one assignment, explicit costs --
    hidden_cost: float = 14.0  # -log-likelihood of a surveyed log the scan shows nothing of (hidden under others):
    #                            dearer than a log on its ridge with one RTK fixed point wrong (~11 nats), so a
    #                            wrong point does not hide its log; a log is never matched with every point wrong [-]
    missed_nats_per_m: float = 4.0  # -log-likelihood of a scan log no surveyed log takes (a log the survey
    #                                 missed), per metre of ridge seen: crews survey every log, so a long ridge
    #                                 left unexplained is unlikely, a short scrap (a branch, a smear) is not [1/m]
    unseen_nats_per_m: float = 5.0  # a log running on unseen past the scan's ridge to its survey point costs
    #                                 this per metre (each 2 cm bin that shows no top is ~0.5 nats likelier past
    #                                 an end than inside: 25 nats/m; a fifth of that, as most such stretches lie
    #                                 under other logs, where a bin says little) [1/m]
    ridge_overrun_m: float = 0.10  # a scan ridge may run this far past its log's end (the end face, smear) [m]
    ambiguity_nats: float = 2.0  # another assignment that makes a different pile within this of the best is
    #                              as good: the survey cannot settle it (a warning naming the log) [-]
    ambiguity_is_error: bool = False  # stop with AmbiguousSurveyError instead (as rules22 does): on the held-out
    #                                   set's packed piles, float logs beside touching neighbours stopped 4 of
    #                                   the first 10 default surveys
    # -- the pile: every log's pose correction against its evidence and the other bodies (joint_settle) --
    settle_scan_sigma_m: float = 0.02  # a placed log's ends across its axis and in height, 1 sigma, as the pile
    #                                    sees them, for a log NOT fitted to the scan (hidden, seen in part: at
    #                                    least this, else its placement's larger sigma), and for every log with
    #                                    per_log_sigma off (revision 10: at 0.015 m tuning scans refused 6.7 cm
    #                                    moves that revision 22 took; its limit, 8 cm, is refuse_sigma of this) [m]
    per_log_sigma: bool = True  # a log fitted to the scan gets its own sigma from the points on its surface
    #                             (joint_scan_sigma.scan_sigma), not settle_scan_sigma_m: one number for every
    #                             log was too sure for packed logs whose sides neighbours hide (held-out
    #                             packed piles: diameter error ~1 cm median, most of revision 10's refusals) [-]
    sigma_cell_along_m: float = 0.15  # a log's surface is observed in cells this long ... (stereo errors are
    #                                   correlated over a patch: the residuals of 5 cm cells correlate 0.68 at
    #                                   10 cm, 0.51 at 20 cm - the first 6 tuning scans, 31 logs) [m]
    sigma_cell_deg: float = 30.0  # ... and this far round its axis (cells 30 deg apart correlate 0.39, 60 deg
    #                               apart not at all: same scans) [deg]
    sigma_bias_share: float = 0.6  # the share of a cell's residual variance that every cell of its angle bin
    #                                shares along the whole log (a stereo bias by the view angle, not noise: 15 cm
    #                                cells correlate 0.6-0.7 at 0.45-1 m apart, same scans), so a longer log
    #                                is hardly surer, a wider arc is [-]
    sigma_cell_min_m: float = 0.003  # a cell's mean is never surer than this (the profiles' 2.5 mm grid, stereo
    #                                  depth steps at 3 m) [m]
    sigma_radius_prior_m: float = 0.03  # a log's radius before its surface is seen: the generator's and a
    #                                     pile's logs span 5-20 cm radii [m]
    sigma_shape_per_radius: float = 0.15  # the log is not round, and stereo smears a round surface: a round fit to
    #                                       the twin's pentagonal prism (a face 1 - cos 36 deg = 19 % of the
    #                                       radius inside the round, by its roll) or to a stem's ovality is off
    #                                       by a share of the radius whatever the scan shows. Fitted on
    #                                       the first 12 tuning scans (default survey, 92 ends of scan-fitted logs the
    #                                       bodies did not move): 95 % of ends within 2 sigma of the truth at
    #                                       0.15 (flanks 96 %, undersides 91 %); at 0.05 only 64 % / 53 % [-]
    sigma_max_m: float = 0.08  # a scan-fitted log's sigma is at most this (a log seen in part is placed on its
    #                            survey axis to ~4 cm; twice that: the scan's fit is then hardly evidence) [m]
    along_ends: bool = False  # each end's place along its log a state of the pile estimate, held by a
    #                          Gaussian from its own posterior (joint_ends.along_sigmas; a sigma toward the
    #                          log's middle and one away), so a body the log runs into can shorten it where
    #                          its end evidence is weak (a hidden end on a float point) and cannot where it is
    #                          strong (an end the scan sees, or an RTK fixed point holds). Off (the default):
    #                          the pile moves logs across and up only, as in revision 11: on the held-out
    #                          scans the end pressed into a body was mostly right and the body or the
    #                          matching wrong, and a log matched on the wrong ridge was shortened and
    #                          placed 52 cm off instead of refused (docs/reconstruction.md,
    #                          "Joint revision 12") [-]
    along_interval_sigmas: float = 4.0  # an end's along prior costs what its posterior costs this many sigma
    #                                     out on each side (its sigma there: the distance to where the posterior
    #                                     falls this squared over 2 nats under its mode, over this): the
    #                                     refusal's line (refuse_sigma), so a move is refused as the end's own
    #                                     posterior would refuse it, and an end does not slide across a valley
    #                                     between two humps (a Gaussian of the whole spread shortened logs by up
    #                                     to 1 m at under 4 sigma: joint revisions 9-10) [-]
    obstacle_states: bool = True  # each stump and rock a state of the pile estimate (a shift in x and y and an
    #                               erosion of its surface, each a Gaussian of its own scan sigma:
    #                               joint_obstacles), so a contact is shared by the log's evidence and the
    #                               obstacle's instead of taking the obstacle as exact: on held-out scans
    #                               correct RTK fixed ends were refused against stumps or rocks the scan
    #                               makes a few centimetres too big (docs/reconstruction.md, "Joint
    #                               revision 13"). Off: revision 12's fixed obstacles [-]
    flat_stumps: bool = True  # a stump's contact is a flat-topped cone (joint_contact.log_stump_depths). Off
    #                           (revision 12): its axis segment with round ends, so a log lying across its
    #                           top was its top radius (10-17 cm) into it: true logs lying on true stumps
    #                           "interpenetrated" them by 10-13 cm, and six held-out refusals were that
    #                           (docs/reconstruction.md, "Joint revision 13") [-]
    radius_states: bool = True  # each log's radius a state of the pile estimate (joint_radius), a Gaussian of
    #                            its own scan radius sigma (joint_scan_sigma.scan_sigma's radius_m; a log not
    #                            fitted to the scan: sigma_radius_prior_m), thinned with its top kept, so a log
    #                            fitted a few cm too thick in a packed pile is thinned within its uncertainty
    #                            instead of pressed into its neighbour and refused (the largest class of joint-18
    #                            refusals on the final set: docs/reconstruction.md, "The final set read scan by
    #                            scan"). With radius_rescue (on) only where revision 18's fixed radii are
    #                            refused. Off: revisions 13-18's fixed radii [-]
    radius_rescue: bool = True  # the radius states are the second explanation of a pile, not the first: the pile
    #                             is settled with its fitted radii (revision 18) and only when that is refused
    #                             (SeparationError: "its fit or its GNSS end points are wrong") with each radius a
    #                             state; the rescue stands only if the pile it makes is one the report would not
    #                             warn about - every end surer than weak_sigma_m and no survey point called wrong
    #                             (outlier_flag_prob), where the pile check leaves it (joint_rescue). A pile that
    #                             clears only thinned AND doubts its survey has both of the refusal's causes in
    #                             play: it is refused as before. On the tuning rescues it refused 4 of 5 with a
    #                             log 30-150 cm off and kept 7 of 10 within 4 cm (docs/reconstruction.md, "Joint
    #                             revision 20"). Off: radius states everywhere, as the tried revision 19 [-]
    radius_min_share: float = 0.75  # ... and never thinned below this share of its fitted radius: past it a
    #                                 contact moves or refuses the log as before. On the fresh held-out scans
    #                                 the logs thinned and placed right needed at most 19 % off; the one that
    #                                 needed 40 % lay on another's ridge 31 cm off, and was kept at 0.6, refused
    #                                 at 0.75 (docs/reconstruction.md, "Radius states (opt-in, joint
    #                                 revisions 13-14)": chosen on those scans, so still to be judged on
    #                                 others) [-]
    radius_sigma_band_m: float = 0.05  # ... and its radius sigma carries the fit's misfit: the RMS depth of the
    #                                    points inside its fitted surface within this (no other log's) beyond
    #                                    that within the fit's inlier band (joint_scan_sigma.radius_misfit).
    #                                    The inlier band (1.5 cm) keeps only the points that agree with the fit,
    #                                    so a radius 4 cm too big left a third of its true log's points out and
    #                                    its sigma blind to them. Wider than the radius errors the states are
    #                                    for (up to 4 cm on the fresh held-out scans); at 5 cm the two logs
    #                                    whose radii were 3-4 cm too big stood out (misfit 1.3-1.4 cm, the others
    #                                    at most 0.8), at 8 cm a correct log's reached 1.1 (docs/
    #                                    reconstruction.md, "Radius states (opt-in, joint revisions 13-14)") [m]
    obstacle_sigma_floor_m: float = 0.01  # an obstacle's place and surface are never surer than this: half the
    #                                       obstacle stage's 2 cm voxel, whatever its points' spread [m]
    obstacle_sigma_max_m: float = 0.05  # ... and at most this uncertain: stereo smears an edge by up to ~5 cm
    #                                     (fitting revision 23's log tolerance), and a body the scan shows at
    #                                     all is not off by more without looking like something else [m]
    obstacle_sigma_band_m: float = 0.05  # the scan points within this of an obstacle's surface (and more than
    #                                      this above the ground and from any log's surface) are its evidence;
    #                                      the RMS of their signed distances is its sigma: its outline is drawn
    #                                      by its outermost points, so it is off by about their spread, not by
    #                                      the spread over sqrt(n) (the same ~5 cm smear) [m]
    obstacle_sigma_ref_points: float = 50.0  # an obstacle carried by fewer points than this has its sigma grown
    #                                          by sqrt(this / n): its outermost points are then fewer and
    #                                          farther between (the obstacle stage accepts 30 voxels) [-]
    survey_loss_sigmas: float = 3.0  # a kept survey point pulls its log as a Gaussian within this many of its
    #                                  sigmas, by a bounded force past them (soft-L1: a wrong point the end
    #                                  posteriors kept does not drag a log by its distance squared) [-]
    contact_sigma_m: float = 0.002  # an interpenetration this deep costs what a 1-sigma move does: the twin's own
    #                                 contact margin is millimetres, so the bodies win against any evidence
    #                                 within a few sigma [m]
    contact_reach_m: float = 0.15  # bodies farther apart than this beyond touching are not tested (twice the
    #                                most a log moves within refuse_sigma) [m]
    refuse_sigma: float = 4.0  # a log whose evidence costs more than this squared more with the bodies than
    #                            without (a 4-sigma move of one Gaussian: 8 cm of a scan-placed log's end) is
    #                            refused: its fit or its points are wrong, not its noise [-]
    twin_rounds: int = 4  # the twin checks the estimate this many times at most; a contact it still finds is
    #                       allowed less overlap each time, none on the last two [-]
    settle_max_evaluations: int = 150  # least_squares' budget per estimate: a 7-log pile converges in ~30
    #                                    steps; one that has not by 150 is sliding a log along another it lies
    #                                    in (a log on another's ridge: with the ends' places free it crawled
    #                                    400 steps, ~1 min, to a refusal), ~0.15 s a step [-]
    # -- what is reported --
    weak_sigma_m: float = 0.05  # an end less certain than this is a weak estimate (warned about), as in rules22 [m]
    # -- the matching's pose: the scan's offset from the survey a state of the assignment (joint_pose) --
    match_pose_offset: bool = True  # the scan pose's error is one offset shared by every survey point: the
    #                                 assignment is made at the likeliest offset under its prior (FuseConfig
    #                                 pose_sigma_m per axis). Off (revision 13): each point scored alone with
    #                                 pose_sigma_m (1 cm, the registered pose's) while matching runs on the pose
    #                                 before registration, 1.5-11.5 cm off on held-out scans: in packed piles
    #                                 every point then lay between two ridges and logs took neighbours' ridges
    #                                 (docs/reconstruction.md, "Joint revision 14: the scan's offset a state of
    #                                 the matching") [-]
    match_pose_reach_sigmas: float = 3.0  # the offset is looked for this many prior sigmas out (12 cm at 4 cm:
    #                                       past it the prior costs over 4.5 nats, a third of hiding a log) [-]
    match_pose_step_m: float = 0.02  # ... on a grid this fine, then refined from its best points: a fifth of the
    #                                  closest ridges' spacing (two 5 cm logs side by side, 10 cm), so the
    #                                  grid lands in every offset's basin [m]
    # -- the matching's ridges: a ridge may run on past its log's end (joint_match.run_on_nats) --
    ridge_run_on: bool = True  # a scan ridge may run on past its log's end onto something in line (a
    #                            neighbour's top, a crossing log's flank): the matching scores a point inside a
    #                            ridge by a mixture of the ridge ending at it and the ridge running on
    #                            (joint_match.run_on_nats). Off (revision 13): a Gaussian of the point's sigma
    #                            alone, so a ridge 20-40 cm past both fixed points of its log made both points
    #                            outliers and the log hidden [-]
    ridge_run_on_prior: float = 0.06  # the share of log ends whose ridge runs on past them by more than
    #                                   ridge_overrun_m: 44 of 760 ridge ends on the first 84 held-out scans
    #                                   (all-fixed survey, the truth's axes; the rest end short of the log's end,
    #                                   median 6 cm) [-]
    ridge_run_on_mean_m: float = 0.33  # ... and how far past ridge_overrun_m on average (an exponential of this
    #                                    mean: the same 44 ends' mean; their whole run past the end: median
    #                                    36 cm, 95 % within 77 cm) [m]
    # -- the matching's ridges: their radius and the ground past them (joint_ridge; joint revision 15) --
    ridge_radius_evidence: bool = True  # a ridge's radius, within its own sigma, is evidence whether it is one log:
    #                                     taking it as a log costs joint_ridge.not_one_log_nats and leaving it
    #                                     unexplained costs that much less. Off (revision 14): a 3 cm "radius"
    #                                     ridge was as good a partner as any (docs/reconstruction.md, "Joint
    #                                     revision 15") [-]
    ridge_chunk_m: float = 0.5  # a ridge's radius is fitted again on chunks this long (thousands of points at
    #                             stereo density); their RMS about the whole run's radius is its sigma: on the
    #                             tuning seeds' 385 ridges on true logs, 77 % of radius errors within 1 sigma,
    #                             97 % within 2 [m]
    ridge_radius_sigma_floor_m: float = 0.005  # ... never surer than this: two profile grid steps (2.5 mm) [m]
    ridge_radius_sigma_prior_m: float = 0.03  # ... and this where fewer than two chunks explain a circle: the
    #                                           radius's sigma the matching used before (FuseConfig radius_sigma_m) [m]
    log_radius_min_m: float = 0.05  # one log's radius lies between this ... (the field's and the generator's
    #                                 logs: 5-20 cm radii, sigma_radius_prior_m's comment) [m]
    log_radius_max_m: float = 0.20  # ... and this [m]
    other_radius_span_m: float = 0.45  # a ridge that is not one log (a scrap, a flank, two logs together) has a
    #                                    profile radius anywhere in the profile search's span
    #                                    (scan_logs.PROFILE_MAX_RADIUS_M) [m]
    not_one_log_max_nats: float = 10.0  # the radius's evidence is bounded at this (the profile's search can be
    #                                     wrong however tight its chunks agree: as sure as an outlier point) [-]
    ridge_coverage: bool = True  # a log matched to a ridge lies along its axis for its surveyed length: where the
    #                              scan sees below that axis past the ridge's ends, no log is there
    #                              (joint_match.coverage_nats, joint_ridge.open_length_m), each metre costing
    #                              coverage_nats_per_m. Off (revision 14): a log on a 10 cm scrap with its far
    #                              point an outlier paid nothing for the 2 m of open ground it would lie over [-]
    coverage_cell_m: float = 0.04  # the height raster's cell for that test: two of the scan-log raster's 2 cm
    #                                bins, so a stereo hole in one does not read as open [m]
    open_drop_m: float = 0.03  # the scan sees "below the axis" where the highest point of a cell is this far
    #                            under it (stereo depth noise ~1 cm at 3 m, a log's taper over a cell) [m]
    coverage_nats_per_m: float = 7.0  # what a metre of open ground costs a log laid along a ridge: the slope of the
    #                                   log-likelihood ratio of its open length, an exponential fitted to the
    #                                   true pairs' (13 of 385 show any, mean 11 cm) against one fitted to the
    #                                   other pairs' (73 of 111 within 30 nats, mean 54 cm): 1/0.11 - 1/0.54 per m.
    #                                   The first 84 held-out scans, all-fixed survey (docs/reconstruction.md,
    #                                   "Joint revision 15") [1/m]
    # -- the matching's ridges: where their axis runs (joint_ridge.RidgeLine; joint revision 16) --
    ridge_chunk_line: bool = True  # a survey point is measured against the line through the ridge's chunk
    #                                profile circles' centres (across and in height), that line's prediction
    #                                variance added to the point's own: a short ridge's direction corrected, a
    #                                ridge that is not straight (one log, then something else in line) a weaker
    #                                test. Off (revision 15): against the whole run's straight axis, as sure at
    #                                a metre past its end as on it (docs/reconstruction.md, "Joint revision 16") [-]
    ridge_line_min_chunks: int = 3  # ... with at least this many chunks explaining a circle (two make a line with
    #                                 no residual to say how straight the ridge is) [-]
    ridge_line_sigma_floor_m: float = 0.005  # ... the chunk centres' scatter about their line taken as at least
    #                                          this: two profile grid steps (2.5 mm), as ridge_radius_sigma_floor_m [m]
    laid_unseen: bool = True  # a two-point log's run past its ridge's ends that none of its points reaches is
    #                           paid by the log laid along the ridge (joint_match.laid_nats, unseen_nats_per_m a
    #                           metre, as its open ground is), outside its points' outlier mixture: a log on a
    #                           10 cm scrap with its far point an outlier pays for the 2 m of it the scan does not
    #                           show. Off (revision 15): each point paid for the run to it, nothing once it was an
    #                           outlier [-]
    run_on_chunks: bool = False  # a point inside a ridge (the ridge running on past it) is tested against the
    #                              ridge's chunks past it (joint_match.run_on_evidence_nats): chunks off the
    #                              line through the log's two points are something else in line (the point is
    #                              the log's end), chunks on it the log running on (the point is wrong). Off by
    #                              default: on a fresh held-out scan it kept a fixed end in the matching but
    #                              the end model still moves it, and with the chunk line it refused a degraded
    #                              scan revision 15 placed (docs/reconstruction.md, "Joint revision 16") [-]
    ridge_direction_sigma_m: float = 0.02  # the line's prior: the whole run's direction is right within this over
    #                                        its seen length (the run's axis within FuseConfig axis_sigma_m across,
    #                                        radius_sigma_m in height). On the tuning seeds' 385 ridges on true
    #                                        logs (all-fixed survey) the direction error times the seen length has
    #                                        an RMS of 1.3-2.6 cm in each band of seen length [m]
    # -- the laid log's unseen run with its length's sigma (joint_match.unseen_run_nats; joint revision 17) --
    laid_length_sigma: bool = True  # the unseen run laid_unseen charges is priced over the surveyed length's
    #                                 error (the two points' sigmas along the ridge's axis, combined): the
    #                                 charge marginalised over the true length, relative to a run of 0. An RTK
    #                                 fixed length (1.5 cm) is charged as before, a float one (25 cm a point)
    #                                 less. Off (revision 16): the length as exact - a float log laid along its
    #                                 own ridge paid for metres its points' error alone explains
    #                                 (docs/reconstruction.md, "Joint revision 17") [-]
    # -- what a bin past the seen top says (joint_view; joint revision 19) --
    view_test: bool = False  # a bin along a log reads 'below' or 'over' (evidence that the log ends before it)
    #                         only where the log's top there lies inside both images of some stereo pair
    #                         (joint_view.in_view): a raised log running out of the pairs' views shows them the
    #                         ground under it before its top leaves the images (10-15 such bins of ground threw
    #                         out correct RTK fixed points 50-95 cm on along the axis: docs/reconstruction.md,
    #                         "The final set read scan by scan"). On in the tried revision 19, which did not beat
    #                         revision 18 on new seeds: off, revision 18's bins [-]
    # -- the direction the laid log is laid in (joint_match.laid_direction; joint revision 18) --
    laid_survey_direction: bool = True  # the log laid_nats lays runs in the inverse-variance weighted direction
    #                                     of the ridge's axis (ridge_direction_sigma_m over its seen length) and
    #                                     the line through its two survey points (their sigmas across it over
    #                                     their distance): a 10 cm scrap across a log's two RTK fixed points says
    #                                     nothing of which way it runs, a long ridge more than two float points.
    #                                     Off (revision 17): along the ridge's axis whatever its seen length
    #                                     (docs/reconstruction.md, "Joint revision 18") [-]

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.type in (bool, "bool"):
                continue
            if not getattr(self, f.name) > 0:
                raise ValueError(f"JointConfig.{f.name} must be > 0, got {getattr(self, f.name)}")
        for name in ("outlier_prior", "outlier_flag_prob", "ridge_run_on_prior", "sigma_bias_share", "p_on_inside",
                     "p_below_inside",
                     "p_on_outside", "p_below_outside", "p_over_inside", "p_over_outside"):
            if not getattr(self, name) < 1:
                raise ValueError(f"JointConfig.{name} is a probability: must be in (0, 1), got {getattr(self, name)}")
        for name in ("laid_length_sigma", "laid_survey_direction", "view_test", "radius_states", "radius_rescue"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"JointConfig.{name} is a switch: must be True or False, got "
                                 f"{getattr(self, name)!r}")
        if not self.log_radius_min_m < self.log_radius_max_m < self.other_radius_span_m:
            raise ValueError(f"JointConfig: log_radius_min_m < log_radius_max_m < other_radius_span_m must hold, got "
                             f"{self.log_radius_min_m}, {self.log_radius_max_m}, {self.other_radius_span_m}")
        if not self.radius_min_share < 1:
            raise ValueError(f"JointConfig.radius_min_share is a share of the fitted radius: must be in (0, 1), "
                             f"got {self.radius_min_share}")
        if (self.p_on_inside + self.p_below_inside + self.p_over_inside > 1
                or self.p_on_outside + self.p_below_outside + self.p_over_outside > 1):
            raise ValueError("JointConfig: p_on_* + p_below_* + p_over_* must not exceed 1 (a bin may also be unseen)")
