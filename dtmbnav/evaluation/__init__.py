"""The research harness: Monte Carlo evaluation, the results file and its check, the accuracy, weak-signal, front-end
and field checks, the benchmarks, and Dask for campaigns that outgrow one process."""
