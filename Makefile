# Two commands do everything on a fresh machine:
#   make run    set up .venv (pinned) and run the main job
#   make test   set up .venv (pinned) and run the tests
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench lint setup clean peers

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q -c constraints.txt torch==2.13.0
	$(BIN)/pip install -q -c constraints.txt -e ".[train,dev]"
	touch $(STAMP)

setup: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest tests

run: $(STAMP)
	$(BIN)/python -m cotrain.main_job

bench: $(STAMP)
	$(BIN)/python -m calib_eval.benchmark.timing
	$(BIN)/python -m calib_eval.benchmark.detector_shape --json docs/results/detector_shape.json
	$(BIN)/python -m calib_eval.benchmark.tag_seeding --runs 3 --json docs/results/tag_seeding.json

# Optional AprilGrid evaluation peers (python -m calib_eval.detection.tags). --no-deps: aprilgrid
# asks for opencv-python, which would overwrite opencv-python-headless's cv2.
peers: $(STAMP)
	$(BIN)/pip install -q --no-deps "aprilgrid==0.5.0" "pupil-apriltags==1.0.4.post11"

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) runs/tiny
