"""va-plugin inside nerfstudio: ``ns-train va-neus | va-ngp | va-plugin-neus`` and the ``va-generator``
dataparser.

Only nerfstudio's entry points import these modules (``nerfstudio.method_configs`` and
``nerfstudio.dataparser_configs`` in ``setup.py``); ``import va_plugin`` never imports nerfstudio. The
environment they run in is set up by ``make nerfstudio`` (``scripts/setup_nerfstudio.sh``).

The parts wrap ours behind nerfstudio's interfaces rather than re-implementing them:

* :mod:`.dataparser`: our generator readers (SyncDreamer strip, Zero123++ grid, Wonder3D folder,
  transforms.json) as a nerfstudio ``DataParser``;
* :mod:`.datamanager`: our DataManager (the same rays, the same sampler seed) as a nerfstudio
  ``DataManager``;
* :mod:`.model`: our NeuS / NGP models and the view-adaptive field behind nerfstudio's ``Model``
  (and our fields behind its ``Field``), rendering the viewer's cameras;
* :mod:`.pipeline`: the pipeline, our training callbacks (the three view-adaptive phases, the step
  schedules, the learning-rate schedule) as nerfstudio training callbacks, and a checkpoint in our format
  beside nerfstudio's so that ``va-export mesh --load-dir <ns run>`` exports the run;
* :mod:`.methods`: the method specifications, made from our registered methods.
"""
