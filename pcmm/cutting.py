__import__("pcmm._moved", fromlist=["moved"]).moved(__name__, "pcmm.events.cutting")  # deprecated path
