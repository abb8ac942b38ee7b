"""Recordings of a cell: what a real cell records (camera images, joint states, optionally the
part's true pose) as ROS 2 messages in an MCAP file or a rosbag2 folder, written by a run
(``cellsight run --record``: :mod:`.recorder`) and tracked offline (``cellsight track``:
:mod:`.track`).

- :mod:`.names`: the topic and joint-name conventions, and the YAML topic map that overrides
  them;
- :mod:`.recorder`: writes a run's sensor data as it goes;
- :mod:`.reader`: opens an MCAP file or a rosbag2 folder (MCAP or SQLite storage), lists its
  topics and decodes their messages;
- :mod:`.images`: ``sensor_msgs/Image`` and ``CompressedImage`` to grayscale arrays;
- :mod:`.series`: joint states, jaw openings and true poses as time series, interpolated;
- :mod:`.frames`: the images grouped by stamp into frames, with the joints at each frame;
- :mod:`.track`: the tracker over the frames, into a run folder
  (:func:`cellsight.recording.track.track_recording`; not imported here, since the run loop
  imports the recorder).
"""

from cellsight.recording.names import TopicMap, load_topic_map

__all__ = ["TopicMap", "load_topic_map"]
