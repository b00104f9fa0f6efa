"""A checkpoint's pickled config written before an option existed still loads, with the option's default."""

import pickle

from va_plugin.fields.sdf_field import SDFFieldConfig
from va_plugin.models.neus import NeuSModelConfig


def test_options_added_after_a_run_was_written_take_their_defaults():
    config = NeuSModelConfig(eikonal_weight=0.3)
    del config.__dict__["field"]  # as a config pickled before these options existed
    del config.__dict__["mask_weight"]
    restored = pickle.loads(pickle.dumps(config))
    assert restored.eikonal_weight == 0.3  # what the run had is kept
    assert restored.mask_weight == 0.1 and isinstance(restored.field, SDFFieldConfig)
    assert restored.field is not NeuSModelConfig().field  # a fresh default, not a shared one
