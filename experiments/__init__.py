"""Experiments apart from the product: the harnesses that measure it, not parts the field stack runs.

* :mod:`.real_test` — the real test: twin scans reconstructed, planned on, executed on the true pile;
* :mod:`.case_studies` — the paper's case-study figures (obstacles, packed piles, log counts).
* :mod:`.learning_curve` — the planner trained on nested shares of the data, evaluated on the same piles.

They use every product package (``synth``, ``planner``, ``reconstruct``, ``field``); no product module
imports them (``tests/test_architecture.py``). ``bench/`` and ``scripts/`` call them.
"""
