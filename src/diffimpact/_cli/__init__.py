"""The ``diffimpact`` command line: ``demo``, ``simulate``, ``fit`` (with
posteriors and hold-out prediction) and ``sweep``.  It imports the library
lazily, so that ``diffimpact --help`` answers at once; every error becomes
one message on stderr, never a traceback.
"""

from ._main import main as main
