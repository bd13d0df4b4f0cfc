# loggrasp — the two commands of the README, plus benchmarks.
.PHONY: setup demo test bench clean

setup:
	./scripts/setup.sh

demo: setup
	.venv/bin/loggrasp demo --out out/demo

test: setup
	.venv/bin/python -m pytest -q -p no:cacheprovider

bench: setup
	.venv/bin/python bench/run.py --out docs/benchmarks.md

clean:
	rm -rf out .pytest_cache
