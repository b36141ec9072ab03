"""The `Example::` blocks of the extension points run as doctests in the fast tier (issue 50, item 7): a contract's
example that no longer runs fails here. To add a module's examples, add its name to `MODULES` (its examples
written as ``>>>`` lines)."""
from __future__ import annotations

import doctest
import importlib

import pytest

#: the modules whose docstrings' examples are run: the extension points' tables and contracts
MODULES = (
    "mcdp.inputs",   # InputField, DepthInput, RigBatch: a method's own input
    "mcdp.metrics",  # Metric, METRICS: a metric and its direction
    "study.sweep.variants",  # Variant, VARIANTS: a way the sweep evaluates a run
    "synth.label_kinds",  # LabelKind: a label a render writes
    "synth.camera",  # CameraModel, MODELS: a lens model (project, unproject, resize, JSON)
    "mcdp.camera",  # TorchModel, TORCH_MODELS: the lens models' torch twins
)


@pytest.mark.parametrize("name", MODULES)
def test_the_examples_of_an_extension_point_run(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    tests = [t for t in finder.find(module, name) if t.examples]
    assert tests, f"{name}: no >>> example in its docstrings (an extension point shows one)"
    tables = {k: sorted(map(str, v)) for k, v in vars(module).items() if k.isupper() and isinstance(v, dict)}
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for t in tests:
        runner.run(t)
    res = runner.summarize(verbose=False)
    assert res.failed == 0, f"{name}: {res.failed} of {res.attempted} examples failed (the output above)"
    after = {k: sorted(map(str, v)) for k, v in vars(module).items() if k.isupper() and isinstance(v, dict)}
    assert after == tables, f"{name}: an example left a table changed (it removes what it registers)"
