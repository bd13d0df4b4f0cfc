"""The conventions every side of a seam shares, with no simulator behind them (no pybullet, no
scene, no renderer): pile frame, pixels and the grasp-angle convention (:mod:`.frames`), the grasp
``(x, y, phi, w)`` (:mod:`.grasp`), the pile ↔ site ↔ SWEREF 99 TM / RH 2000 conversions
(:mod:`.geodesy`) and the stereo calibration formats (:mod:`.calibration`). The simulator writes
them; reconstruction and the field stack read them."""
