"""Event restoration of recordings (``rdnet restore``): the :class:`Restorer` protocol,
the classical restorers and the streamed runner. The learned restorer lives in
:mod:`rdnet.restore.learned` (imported only when asked for)."""
from rdnet.restore.base import BafRestorer, GefRestorer, RawRestorer, Restorer, StcfRestorer, get_restorer
from rdnet.restore.settings import METHODS, RestoreConfig

__all__ = ["BafRestorer", "GefRestorer", "METHODS", "RawRestorer", "RestoreConfig", "Restorer",
           "StcfRestorer", "get_restorer"]
