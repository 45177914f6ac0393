"""Captions at three tiers (short / concise / detailed).

``StubCaptioner`` (offline, deterministic, grounded in the asset) and ``HttpCaptioner`` (an OpenAI-compatible
or Gemini endpoint through httpx) both follow the :class:`~mixcount.captions.base.Captioner` protocol.
Submodules are imported lazily by callers so ``import mixcount.captions`` stays light.
"""

from mixcount.captions.base import TIERS, Captioner, CaptionInput, CaptionResult

__all__ = ["TIERS", "CaptionInput", "Captioner", "CaptionResult"]
