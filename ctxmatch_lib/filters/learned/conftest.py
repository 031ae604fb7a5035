"""pytest: the doctest run over the package (``--doctest-modules ctxmatch_lib``) skips the modules that import
torch when torch is absent: training and the torch modules (the filters' numpy inference, ``npnets.py``, needs
no torch; torch's own tests skip with a reason in tests/test_learned_filters.py)."""

import importlib.util

collect_ignore = [] if importlib.util.find_spec("torch") else ["nets.py", "checkpoints.py", "training.py"]
