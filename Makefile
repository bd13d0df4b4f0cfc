# loggrasp — the two commands of the README, plus benchmarks.
.PHONY: setup demo test soak bench safety-case clean

setup:
	./scripts/setup.sh

demo: setup
	.venv/bin/loggrasp demo --out out/demo

test: setup
	.venv/bin/python -m pytest -q -p no:cacheprovider -n 2 --dist loadfile

# the link soak at full size on every backend, authenticated, every transmission error class injected
# (the default suite runs 4,000 on CAN, 2,000 on Zenoh; make safety-case 8,000 and 2,000; docs/link-safety.md "Soak")
soak: setup
	LOGGRASP_SOAK_CAN_N=100000 LOGGRASP_SOAK_ZENOH_N=20000 .venv/bin/python -m pytest -q -s -p no:cacheprovider tests/field/test_link_soak.py

# docs/safety-case.md from a run of the tests marked safety_case (transmission errors x links)
safety-case: setup
	PYTHONPATH=. .venv/bin/python scripts/safety_case.py --out docs/safety-case.md

bench: setup
	.venv/bin/python bench/run.py --out docs/benchmarks.md

clean:
	rm -rf out .pytest_cache
