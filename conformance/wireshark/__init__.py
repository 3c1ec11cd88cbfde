"""The Wireshark dissector: ``dissector`` generates it from the specs (``specs export
--wireshark``), ``lua`` holds its Lua body."""
