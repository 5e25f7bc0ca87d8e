"""Dataset entry points for ``configs/dataset/*.yaml``: each builds a :class:`data.multiview.Sequence`."""
from __future__ import annotations

from data.multiview import Sequence


def synthetic(**options) -> Sequence:
    """The built-in synthetic crowd; options are the fields of ``data.synthetic.SyntheticConfig``."""
    from data.synthetic import SyntheticConfig, generate_sequence

    return generate_sequence(SyntheticConfig(**options))
