__import__("pcmm._moved", fromlist=["moved"]).moved(__name__, "pcmm.run.checks")  # deprecated path
