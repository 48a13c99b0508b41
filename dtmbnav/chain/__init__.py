"""The processing chain on files: a capture received, a walk's PDR and fusion, the report, a capture set run.

This is the product's real-data path: it reads what an SDR and a phone recorded and never imports the simulator.
"""
