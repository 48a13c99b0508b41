"""What a field recording needs: the phone's own logs, the sensors import, the towers file and the map files."""
