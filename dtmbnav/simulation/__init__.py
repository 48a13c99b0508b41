"""The simulator wired to the receiver and the chain: a scenario's capture set, its IQ received, the demo."""
