"""The fitting stage: survey and scan fused by their uncertainties (:mod:`.fuse`) and each log
fitted as a cylinder, then the pile assembled and checked in the twin (:mod:`.fit`)."""
