"""A checkpoint's pickled config written before an option existed still loads, with the option's default."""

import pickle

from va_plugin.models.neus import NeuSModelConfig


def test_options_added_after_a_run_was_written_take_their_defaults():
    config = NeuSModelConfig(eikonal_weight=0.3)
    del config.__dict__["camera_opt"]  # as a config pickled before camera refinement existed
    del config.__dict__["smoothness_weight"]
    restored = pickle.loads(pickle.dumps(config))
    assert restored.eikonal_weight == 0.3  # what the run had is kept
    assert restored.smoothness_weight == 0.0 and restored.camera_opt.mode == "off"
    assert restored.camera_opt is not NeuSModelConfig().camera_opt  # a fresh default, not a shared one
