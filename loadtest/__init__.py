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
