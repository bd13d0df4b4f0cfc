"""loggrasp planner: the paper's grasp-map U-Net, its training and multi-log grasp planning.

Entry points (torch is imported lazily, inside the functions):

* :func:`planner.train.train` ``(data_dir, out_dir, config: TrainConfig, progress=None) -> TrainResult``
* :func:`planner.inference.load_planner` ``(path, device="auto", precision="auto", batch_size=None) -> Planner``
* :func:`planner.inference.plan` ``(observation, planner, objective=Objective(), constraints=Constraints(),
  top_k=None, *, subsets=SubsetPolicy(), pile=None) -> Plan`` (``Plan.to_json()``)
* :func:`planner.checkpoint.save_checkpoint` / :func:`planner.checkpoint.load_checkpoint`
"""
