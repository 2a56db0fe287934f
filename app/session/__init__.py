"""Sessions: the one typed tick record (`schema`), its writer and its reader, the camera
frames beside them (`video`), and a run's records as columns (`trace`)."""
