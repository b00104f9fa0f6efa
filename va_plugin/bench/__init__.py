"""The paper's experiments as benchmarks: paired original-vs-adaptive runs on benchmark scenes.

The scripts in ``benchmarks/`` only describe their rows and report; :mod:`presets` holds the presets,
:mod:`scenes` the scene names and cache, :mod:`rows` one training run of one method on one scene,
:mod:`store` the finished rows (``rows.jsonl``), :mod:`report` tables and plots, :mod:`parallel` worker
processes (``--jobs N``) and :mod:`cli` the shared command line.
"""
