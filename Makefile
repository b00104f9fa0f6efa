# The commands of the README. Each runs the setup first (it is quick once done).
.PHONY: setup demo test lint app browser-check nerfstudio test-nerfstudio

.venv/.va-setup-done: setup.py scripts/setup.sh
	bash scripts/setup.sh

setup: .venv/.va-setup-done

demo: setup
	.venv/bin/va-demo

app: setup
	.venv/bin/va-app

# va-app in headless Chromium (Debian's; --install: apt-get it when missing): upload, run, screenshot
browser-check: setup
	.venv/bin/python scripts/browser_check.py --install --out outputs/browser_check/page.png

lint: setup
	.venv/bin/ruff check .

test: lint
	.venv/bin/python -m pytest -q

# nerfstudio 1.1.5 with the CPU build of torch in its own environment, .venv-ns/ (ns-train va-neus, ...)
.venv-ns/.va-ns-setup-done: setup.py scripts/setup_nerfstudio.sh scripts/nerfstudio_requirements.py
	bash scripts/setup_nerfstudio.sh

nerfstudio: .venv-ns/.va-ns-setup-done

# ns-train and the export on a tiny scene, for each method registered in nerfstudio
test-nerfstudio: nerfstudio
	.venv-ns/bin/python -m pytest -q tests/nerfstudio_plugin
