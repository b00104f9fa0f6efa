"""The paper's experiments as benchmarks: paired original-vs-adaptive runs on benchmark scenes.

The four scripts in ``benchmarks/`` (``run_table1.py``, ``run_views.py``, ``run_ablation.py``,
``run_sweep.py``) only describe their rows and their report; everything else lives here:

* :mod:`presets`: the ``smoke`` / ``quick`` / ``full`` presets (scenes, step budgets, evaluation settings);
* :mod:`scenes`: scene names on the command line, and the scene cache under ``--out``;
* :mod:`rows`: one row = one training run of one method on one scene, trained and evaluated through the
  library (registry, trainer, ``va_plugin.eval``), with checkpoints along the run for time-vs-error curves;
* :mod:`store`: the finished rows on disk (``rows.jsonl``), which ``--resume`` reads;
* :mod:`report`: CSV, JSON, Markdown tables (mean and spread over scenes) and plots;
* :mod:`parallel`: rows in worker processes (``--jobs N``);
* :mod:`cli`: the shared command line, the loop over rows with progress, and the final summary.
"""
