"""The run: the configuration-complete loop of the paper's Fig. 3, its checks and diagnostics."""
