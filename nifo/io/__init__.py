"""File and bag I/O: everything that turns files into ``nifo_core.signal.record.Record`` and results into files."""
