"""bodebench instrument: sampler, stopping rules, results, sweeps and the command line."""
