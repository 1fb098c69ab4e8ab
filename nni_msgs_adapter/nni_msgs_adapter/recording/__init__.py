"""Recording: the MCAP writer and reader, the logger node, runs read back from recordings, replay."""
