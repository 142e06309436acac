"""Load generator for the IK service: simulated game clients streaming smooth target paths.

``python -m loadtest --help`` runs it; ``loadtest.floors`` holds the bare echo apps that
give the floors the service is compared with, ``loadtest.serve`` the multi-worker
deployment, ``loadtest.capacity`` the capacity search behind bench/RESULTS.md,
``loadtest.cost`` the server CPU per frame at one load and ``loadtest/locustfile.py`` the
same scenarios for Locust. The longer runs against a server they start themselves:
``loadtest.soak`` (memory and leftovers over time), ``loadtest.fuzz`` (schemathesis with
many examples) and ``loadtest.ws_inline_vs_thread`` (inline solving versus a thread
pool). ``loadtest.service_process`` starts a real ``python -m service`` and waits for
/readyz (also for bench/cold_start.py and the live tests); ``loadtest.cli`` holds the
load options the command lines share.
"""

import sys
from pathlib import Path

# The load tools drive the service through the repository's own Python client
# (clients/python, a package of its own), imported from the checkout as the tests do
# (pytest's ``pythonpath``): the load tools run from a checkout, never from an install.
_CLIENT = Path(__file__).resolve().parent.parent / "clients" / "python"
if str(_CLIENT) not in sys.path:
    sys.path.append(str(_CLIENT))
