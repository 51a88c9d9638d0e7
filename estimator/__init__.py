"""The estimator: camera models, ego-motion and surround analysis of any recording.

It never imports sim/ or scenarios/ (`tests/test_layout.py`): it runs on real recordings.
"""
