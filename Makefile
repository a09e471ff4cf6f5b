# Two commands: `make demo` and `make test`. Both create .venv on first use.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv demo test lint soak bench clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip >/dev/null 2>&1 || true
	$(VENV)/bin/pip install -q -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/fleet demo

test: $(STAMP)
	$(PY) -m tests.lanes

lint: $(STAMP)
	$(VENV)/bin/ruff check .

soak: $(STAMP)
	$(VENV)/bin/pytest -m soak -o addopts='-q'

# Every paper reproduction -> docs/results.md + docs/results/*.png (JSON under out/results/), ~10 min.
.PHONY: results
results: $(STAMP)
	nice -n 10 $(PY) -m bench.results

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
