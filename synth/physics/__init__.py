"""The physics twin: the pybullet world built from a pile (:mod:`.world`, its collision meshes in
:mod:`.meshes`), the grapple (:mod:`.grapple`) and the grasp trial (:mod:`.trial`,
``run_trial``, ``TRIAL_REVISION``)."""
