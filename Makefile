# The two set-up commands of the README: `make demo` and `make test`. Both create .venv and
# install torch (the CPU build, before stable-baselines3 so pip does not fetch a CUDA build),
# then hexgym with its extras.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.hexgym-installed
export MUJOCO_GL ?= egl

.PHONY: demo test test-python test-slow lint ci setup clean agent

setup: $(STAMP)

$(STAMP): pyproject.toml setup.py $(wildcard native/*.cc native/*.h)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e ".[train,video,plots,dev,cluster,logs]"
	touch $@

demo: $(STAMP)
	$(BIN)/hexgym demo --out out
	@# the trained agent too, when the package ships one
	@if [ -f hexgym/policies/ppo_loading.zip ]; then \
		$(BIN)/hexgym video --policy shipped --out out/agent.mp4 --seconds 60 --snapshot out/agent.png; fi

test: $(STAMP)
	$(BIN)/python -m pytest -q

# the learned-model and environment tests once more on the Python backend, where the plugin is built too
test-python: $(STAMP)
	HEXGYM_BACKEND=python $(BIN)/python -m pytest -q tests/test_learned.py tests/test_env.py tests/test_scripted.py \
		tests/test_vector_env.py tests/test_task.py tests/test_table_sets.py

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check hexgym hexgym_lab experiments tests assets setup.py
	$(BIN)/ruff format --check hexgym hexgym_lab experiments tests assets setup.py

# the shipped agent's recipe (docs/agents.md#the-shipped-agent), ~40 min on 2 cores: the loader with its searched
# settings cloned with DAgger, PPO on the task's reward from the clone, the checkpoint that loads most on the
# selection seeds kept
AGENT := out/agent
agent: $(STAMP)
	$(BIN)/hexgym clone --out $(AGENT)/clone.zip --episodes 16 --dagger-rounds 12 --dagger-episodes 16 --noise 0.2 \
		--epochs 25 --select-episodes 10 --loader-settings training/loader_teacher.json
	$(BIN)/hexgym train --algo ppo --init-from $(AGENT)/clone.zip --hyperparams hexgym_lab/hyperparams/ppo_finetune.yml \
		--checkpoint-every 100000 -f $(AGENT)/finetune
	$(BIN)/hexgym select $(AGENT)/finetune/ppo_HexLoading-v0/checkpoints --out $(AGENT)/ppo_loading.zip \
		--json $(AGENT)/selection.json
	$(BIN)/hexgym curves $(AGENT)/finetune/ppo_HexLoading-v0 --out $(AGENT)/curve.png

# what CI runs: the README's test command, the linter, the Python backend's run
ci: test lint test-python

clean:
	rm -rf $(VENV) out build *.egg-info
