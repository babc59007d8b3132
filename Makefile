# The two set-up commands of the README: `make demo` and `make test`. Both create .venv and
# install torch (the CPU build, before stable-baselines3 so pip does not fetch a CUDA build),
# then hexgym with its extras.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.hexgym-installed
export MUJOCO_GL ?= egl

.PHONY: demo test test-slow lint setup clean

setup: $(STAMP)

$(STAMP): pyproject.toml setup.py $(wildcard native/*.cc native/*.h)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e ".[train,video,plots,dev]"
	touch $@

demo: $(STAMP)
	$(BIN)/hexgym demo --out out
	@# the trained agent too, when the package ships one
	@if [ -f hexgym/policies/ppo_loading.zip ]; then \
		$(BIN)/hexgym video --policy shipped --out out/agent.mp4 --seconds 60 --snapshot out/agent.png; fi

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check hexgym tests training assets
	$(BIN)/ruff format --check hexgym tests training assets

clean:
	rm -rf $(VENV) out build *.egg-info
