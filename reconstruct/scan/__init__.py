"""The scan stage: stereo pairs and their calibration (:mod:`.calibration`), the scan's point cloud
(:mod:`.stereo`), the pairs' poses from structure from motion (:mod:`.sfm`) and the twin's own
field scans (:mod:`.twin_scan`)."""
