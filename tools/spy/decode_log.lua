-- Decodes every message of an LCM log with stitch's generated Lua types (lcm-gen --lua; Debian's
-- liblcm-lua for the `lcm` module they require), the type chosen by the channel's name. Prints
-- one line per channel: channel, type, messages, decoded, undecodable, bytes (of messages) and
-- bytes per second (from the channel's first message to its last); the same columns as
-- `stitch spy --log`. An example for Lua users as much as a check:
--   LUA_PATH="build/share/lua/?.lua;;" lua5.2 tools/spy/decode_log.lua flight.lcmlog

local types = {
  FRAME = 'frame_t', FRAME_ACK = 'frame_ack_t', SEQUENCE = 'sequence_info_t',
  TRACKING_STATUS = 'tracking_status_t', KEYFRAME = 'keyframe_t', LOCAL_MAP = 'local_map_update_t',
  SUBMAP = 'submap_update_t', SUBMAP_REQUEST = 'submap_request_t', GLOBAL_MAP = 'global_map_t',
  SERVICE = 'service_status_t', LINK_STATUS = 'link_status_t', POSE = 'frame_pose_t',
  MAP_CLOUD = 'map_cloud_t', GNSS = 'gnss_fix_t',
}

-- A big-endian unsigned integer of `n` bytes at `at` (1-based); Lua 5.2 has no string.unpack.
local function big_endian(data, at, n)
  local value = 0
  for i = 0, n - 1 do value = value * 256 + data:byte(at + i) end
  return value
end

local path = arg[1]
if not path then
  io.stderr:write('usage: lua5.2 decode_log.lua FILE.lcmlog\n')
  os.exit(2)
end
local file = assert(io.open(path, 'rb'))
local log = file:read('*a')
file:close()

local channels, order = {}, {}
local at = 1
-- Each event: sync word 0xEDA1DA01, event number (8), time (8), channel length (4), data length
-- (4), the channel, the data.
while at + 28 <= #log + 1 do
  if big_endian(log, at, 4) ~= 0xEDA1DA01 then
    io.stderr:write(string.format('%s: no event at byte %d\n', path, at - 1))
    os.exit(1)
  end
  local channel_length = big_endian(log, at + 20, 4)
  local data_length = big_endian(log, at + 24, 4)
  local time = big_endian(log, at + 12, 8)
  local channel = log:sub(at + 28, at + 27 + channel_length)
  local data = log:sub(at + 28 + channel_length, at + 27 + channel_length + data_length)
  at = at + 28 + channel_length + data_length
  local c = channels[channel]
  if not c then
    c = {type = '??', messages = 0, decoded = 0, failed = 0, bytes = 0, first = time}
    channels[channel] = c
    order[#order + 1] = channel
  end
  c.messages = c.messages + 1
  c.bytes = c.bytes + data_length
  c.last = time
  local name = types[channel:match('/([%u_]+)$') or '']
  if name then
    c.type = 'stitch.' .. name
    local ok = pcall(require('stitch.' .. name).decode, data)
    if ok then c.decoded = c.decoded + 1 else c.failed = c.failed + 1 end
  else
    c.failed = c.failed + 1
  end
end

table.sort(order)
print('channel\ttype\tmessages\tdecoded\tundecodable\tbytes\tbytes_per_s')
for _, channel in ipairs(order) do
  local c = channels[channel]
  local span_us = c.last - c.first
  local rate = span_us > 0 and math.floor(c.bytes * 1e6 / span_us) or 0
  print(string.format('%s\t%s\t%d\t%d\t%d\t%d\t%d', channel, c.type, c.messages, c.decoded, c.failed, c.bytes, rate))
end
