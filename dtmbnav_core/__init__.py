"""What every dtmbnav package shares: the foundation under receiver, sim and fusion.

- :mod:`~dtmbnav_core.constants`: physical constants.
- :mod:`~dtmbnav_core.gb20600`: the standard's tables, sequences and constants.
- :mod:`~dtmbnav_core.iqformat`: raw IQ sample formats and their normalisation.
- :mod:`~dtmbnav_core.records`: typed column records (trajectory, IMU, GNSS,
  PDR steps, range series, receiver frames).
- :mod:`~dtmbnav_core.schema`: the HDF5 file schema (group and attribute names).
- :mod:`~dtmbnav_core.h5io`: atomic HDF5 writing and column reading.
- :mod:`~dtmbnav_core.sensors`: typed readers and writers of the sensor and
  truth groups.
- :mod:`~dtmbnav_core.geodetic`: WGS84 latitude, longitude and height to and
  from a local ENU frame.
- :mod:`~dtmbnav_core.phone`: a phone log's clock model and stated fix accuracy.

Nothing here imports ``receiver``, ``sim`` or ``fusion``; they import this and
never each other (README, "Layout").
"""
