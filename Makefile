# The two commands of the README. Both run the setup first (it is quick once done).
.PHONY: setup demo test lint

.venv/.va-setup-done: setup.py scripts/setup.sh
	bash scripts/setup.sh

setup: .venv/.va-setup-done

demo: setup
	.venv/bin/va-demo

lint: setup
	.venv/bin/ruff check .

test: lint
	.venv/bin/python -m pytest -q
