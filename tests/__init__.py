"""Shared helpers of the tests."""


def ski_settings(filt) -> dict:
    """The ARD keyword arguments of skigen.reference.filters.ski_step for a derived SKI."""
    o = filt.options
    return dict(eta=o.eta, n_steps=o.ard_steps, margin=o.margin, s_min=o.s_min, s_max=o.s_max,
                max_step=o.max_step, backtracks=o.backtracks, ard=o.ard, s0=filt.aug.s0, s_floor=o.s_floor)
