"""Load generator for the IK service: simulated game clients streaming smooth target paths.

``python -m loadtest --help`` runs it; ``loadtest.floors`` holds the bare echo apps that
give the floors the service is compared with, ``loadtest.serve`` the multi-worker
deployment, ``loadtest.capacity`` the capacity search behind bench/RESULTS.md and
``loadtest/locustfile.py`` the same scenarios for Locust.
"""
