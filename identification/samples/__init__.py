"""Bus -> frames -> samples: a CAN recording read into the time series of one test."""
