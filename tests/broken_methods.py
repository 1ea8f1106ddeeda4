"""Deliberately broken methods for the conformance check's tests (`strings-bench methods check`).

Each is 3DGS with one fault a real adapter could have; the check must fail and name the check."""

from __future__ import annotations

import numpy as np

from strings_bench.methods.gs3d import GS3D


class DropsTensorOnLoad(GS3D):
    """load_state_dict restores everything but the opacities, which keep the freshly set-up values."""

    def setup(self, scene, **kw):
        super().setup(scene, **kw)
        self._initial_opacity = self.model.params["opacity_logits"].detach().clone()

    def load_state_dict(self, state):
        super().load_state_dict(state)
        self.model.params["opacity_logits"].data.copy_(self._initial_opacity)


class NaNRender(GS3D):
    """Renders NaN everywhere."""

    def render(self, view_idx):
        return np.full_like(super().render(view_idx), np.nan)


class WrongSizeRender(GS3D):
    """Renders one row short."""

    def render(self, view_idx):
        return super().render(view_idx)[:-1]


class ConstantRender(GS3D):
    """Renders a flat grey image."""

    def render(self, view_idx):
        return np.full_like(super().render(view_idx), 0.5)


class UnstableState(GS3D):
    """state_dict() carries a counter that changes on every call, so a re-saved state is never identical."""

    _saves = 0

    def state_dict(self):
        UnstableState._saves += 1
        return {**super().state_dict(), "saves": UnstableState._saves}

    def load_state_dict(self, state):
        super().load_state_dict({k: v for k, v in state.items() if k != "saves"})


class NoSettingsSchema(GS3D):
    """Does not describe its settings."""

    settings_schema = None
