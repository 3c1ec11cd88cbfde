"""The dissector's Lua program, a template :func:`conformance.wireshark.lua_dissector` fills in.

``@NAMES@``, ``@DIALECTS@``, ``@REPLIES@`` and ``@ERRORS@`` become the generated tables
(command names, field dialects, how a lone integer reply reads, chapter 9's codes);
``@TCP_PORT@``, ``@UDP_PORT@``, ``@MAX_FRAME@`` and ``@VERSION@`` the settings.  The
reading (``read_frame``) is :mod:`conformance.protocol.frame`'s, the refusal
(``refusal_of``) :func:`conformance.judge.requests.classify_reply`'s, ported to Lua.
"""

from __future__ import annotations

__all__ = ["LUA"]

LUA = r"""
local fairino = Proto("fairino", "FAIRINO text protocol (spec @VERSION@)")

-- CMD_ID -> names the manual gives it (the adopted command first).
local NAMES = {
@NAMES@
}

-- CMD_ID -> field dialects recorded for it (conformance/dialects.py).
local DIALECTS = {
@DIALECTS@
}

-- CMD_ID -> how a lone integer reply reads (conformance/wireshark.py reply_kind):
-- "e" error code only (1 success, else refused), "m" several values due (0 or a
-- chapter 9 code is a refusal); absent: no numeric refusal.  An ID in neither
-- table above is an unknown command, answered with a code ("e").
local REPLIES = {
@REPLIES@
}

-- Chapter 9 error codes: {meaning (Chinese, manual v3.8.2), meaning (English, v3.9.8)}.
local ERRORS = {
@ERRORS@
}

local MAX_FRAME = @MAX_FRAME@
local MAX_DIGITS = 10
local MAX_SEP = 4
local MAX_HEADER = 4 + 3 * (MAX_SEP + 1) + 3 * (MAX_DIGITS + 1)

local pf = {
  cnt = ProtoField.uint64("fairino.cnt", "CNT", base.DEC),
  cmd_id = ProtoField.uint64("fairino.cmd_id", "CMD_ID", base.DEC),
  name = ProtoField.string("fairino.name", "Command"),
  names = ProtoField.string("fairino.names", "Commands with this ID (manual)"),
  dialect = ProtoField.string("fairino.dialect", "Field dialects"),
  len = ProtoField.uint64("fairino.len", "LEN", base.DEC),
  data = ProtoField.string("fairino.data", "DATA", base.UNICODE),
  data_len = ProtoField.uint32("fairino.data_len", "DATA byte count", base.DEC),
  call = ProtoField.string("fairino.call", "Call"),
  len_mismatch = ProtoField.bool("fairino.len_mismatch", "LEN mismatch"),
  bad_separator = ProtoField.bool("fairino.bad_separator", "Bad separator"),
  unknown_id = ProtoField.bool("fairino.unknown_id", "Unknown command ID"),
  skipped = ProtoField.bytes("fairino.skipped", "Skipped bytes"),
  refused = ProtoField.bool("fairino.refused", "Refused"),
  errcode = ProtoField.int64("fairino.errcode", "Error code", base.DEC),
  errcode_meaning = ProtoField.string("fairino.errcode_meaning", "Meaning (chapter 9)"),
  errcode_meaning_en = ProtoField.string("fairino.errcode_meaning_en", "Meaning (English)"),
}
fairino.fields = pf

local ef = {
  len_mismatch = ProtoExpert.new("fairino.len_mismatch.expert", "LEN disagrees with DATA's byte count",
    expert.group.MALFORMED, expert.severity.WARN),
  bad_separator = ProtoExpert.new("fairino.bad_separator.expert", "Separator is not III",
    expert.group.PROTOCOL, expert.severity.WARN),
  unknown_id = ProtoExpert.new("fairino.unknown_id.expert", "Unknown command ID",
    expert.group.UNDECODED, expert.severity.WARN),
  dialect_id = ProtoExpert.new("fairino.dialect_id.expert", "Command ID not in the manual: a field dialect",
    expert.group.PROTOCOL, expert.severity.NOTE),
  garbage = ProtoExpert.new("fairino.garbage.expert", "Bytes that are not a frame",
    expert.group.MALFORMED, expert.severity.WARN),
  padding = ProtoExpert.new("fairino.padding.expert", "NUL padding",
    expert.group.PROTOCOL, expert.severity.NOTE),
  refused = ProtoExpert.new("fairino.refused.expert", "Refusal",
    expert.group.RESPONSE_CODE, expert.severity.NOTE),
}
fairino.experts = ef

fairino.prefs.tcp_ports = Pref.range("TCP ports", "@TCP_PORT@", "TCP ports to decode as FAIRINO", 65535)
fairino.prefs.udp_ports = Pref.range("UDP ports", "@UDP_PORT@", "UDP ports to decode as FAIRINO", 65535)
fairino.prefs.heuristic = Pref.bool("Heuristic dissector", true,
  "Also decode TCP and UDP payloads that start with /f/bIII on any other port")

local function run_of(s, i, byte, limit)
  -- how many `byte` at s[i..] (at most limit)
  local n = 0
  while n < limit and i + n <= #s and s:byte(i + n) == byte do n = n + 1 end
  return n
end

local function digits_at(s, i, limit)
  local n = 0
  while n < limit and i + n <= #s do
    local b = s:byte(i + n)
    if b < 48 or b > 57 then break end
    n = n + 1
  end
  return n
end

local function find_plain(s, what, from, limit)
  -- first `what` wholly inside s[from..limit]
  local at = s:find(what, from, true)
  if at and at + #what - 1 <= limit then return at end
  return nil
end

-- The frame at s[i] (1-based, s[i..i+3] == "/f/b"), as conformance/frame.py reads it:
--   {kind = "frame", stop = last byte, ...}, {kind = "skip", stop = ..., why = ...} or
--   {kind = "more", need = bytes or nil (one more segment)}.
local function read_frame(s, i, final)
  local n = #s
  local p = i + 4
  local g = {}
  for k = 1, 3 do
    local sep = run_of(s, p, 73, MAX_SEP + 1)
    p = p + sep
    local dig = digits_at(s, p, MAX_DIGITS + 1)
    g[k] = {sep = sep, from = p, dig = dig}
    p = p + dig
  end
  local hdr_end = p -- first byte after LEN's digits
  if hdr_end > n and hdr_end - i < MAX_HEADER and not final then return {kind = "more"} end
  local complete = hdr_end <= n
  for k = 1, 3 do
    if g[k].sep == 0 or g[k].dig == 0 or g[k].dig > MAX_DIGITS then complete = false end
  end
  if not complete then
    return {kind = "skip", stop = math.max(hdr_end - 1, i + 3), why = "broken header"}
  end
  local bad_sep = false
  for k = 1, 3 do
    if g[k].sep ~= 3 then
      if g[k].sep < 2 or g[k].sep > 4 then
        return {kind = "skip", stop = hdr_end - 1, why = "separator is not III"}
      end
      bad_sep = true
    end
  end
  local f = {
    kind = "frame",
    cnt = {g[1].from, g[1].dig}, cmd_id = {g[2].from, g[2].dig}, len = {g[3].from, g[3].dig},
    cnt_v = tonumber(s:sub(g[1].from, g[1].from + g[1].dig - 1)),
    cmd_id_v = tonumber(s:sub(g[2].from, g[2].from + g[2].dig - 1)),
    len_v = tonumber(s:sub(g[3].from, g[3].from + g[3].dig - 1)),
    bad_sep = bad_sep, len_mismatch = false,
  }
  local run = run_of(s, p, 73, 5)
  if run < 2 and p + run <= n then
    return {kind = "skip", stop = p - 1, why = "no separator after LEN"}
  end
  local length = f.len_v
  if (hdr_end - i) + 3 + length + 7 <= MAX_FRAME then
    local ds, de = p + 3, p + 3 + length -- DATA is s[ds..de-1]
    if n < de + 6 then
      if final then
        -- a datagram is all there is: look for the tail below
      elseif run >= 2 and not find_plain(s, "II/b/f", p + 2, n) then
        return {kind = "more", need = de + 6 - n}
      else
        return {kind = "more"}
      end
    elseif s:sub(p, ds - 1) == "III" and s:sub(de, de + 6) == "III/b/f" then
      f.ds, f.de, f.stop = ds, de, de + 6
      return f
    end
  end
  -- LEN disagrees with DATA: the earliest /b/f after two I, before the next head.
  local limit = math.min(n, i + MAX_FRAME - 1)
  local head_at = find_plain(s, "/f/b", p, limit)
  local t_limit = limit
  if head_at then t_limit = math.min(limit, head_at + 2) end
  local q = p + 4
  local tail_at = nil
  while true do
    q = find_plain(s, "/b/f", q, t_limit)
    if not q then break end
    if s:sub(q - 2, q - 1) == "II" then tail_at = q; break end
    q = q + 1
  end
  if head_at and (not tail_at or head_at < tail_at) then
    return {kind = "skip", stop = head_at - 1, why = "frame has no tail"}
  end
  if tail_at then
    local trail = 0
    while trail < 5 and s:byte(tail_at - trail - 1) == 73 and tail_at - trail - 1 >= p + 2 do
      trail = trail + 1
    end
    local ks = (run <= 4) and {run} or {3, 2, 4}
    local ts = (trail <= 4) and {trail} or {3, 2, 4}
    local bk, bt = nil, nil
    for _, k in ipairs(ks) do
      for _, t in ipairs(ts) do
        if not bk and tail_at - t - (p + k) == length then bk, bt = k, t end
      end
    end
    if not bk then
      bk, bt = math.min(run, 3), math.min(trail, 3)
      f.len_mismatch = true
    end
    if bk ~= 3 or bt ~= 3 then f.bad_sep = true end
    f.ds = p + bk
    f.de = math.max(p + bk, tail_at - bt)
    f.stop = tail_at + 3
    return f
  end
  if limit - i + 1 >= MAX_FRAME then
    return {kind = "skip", stop = i + MAX_FRAME - 1, why = "no tail within the frame size bound"}
  end
  if final then return {kind = "skip", stop = n, why = "datagram ends inside a frame"} end
  return {kind = "more"}
end

local function name_of(cmd_id, call)
  local names = NAMES[cmd_id]
  if names then
    if call then
      local low = call:lower()
      for _, nm in ipairs(names) do
        if nm:lower() == low then return nm, names end
      end
    end
    return names[1], names
  end
  local d = DIALECTS[cmd_id]
  if d then return d.name, nil end
  return "", nil
end

local MAX_CODE_DIGITS = 18 -- conformance/validate.py: a longer run of digits is no code

local function code_of(digits)
  -- "[+-]?%d+" -> Int64 value, a Lua number where exact (table key), text; nil if too long
  local neg = digits:sub(1, 1) == "-"
  local body = digits:gsub("^[%+%-]", ""):gsub("^0+(%d)", "%1")
  if #body > MAX_CODE_DIGITS then return nil end
  local v = Int64(0)
  for k = 1, #body do v = v * 10 + (body:byte(k) - 48) end
  if neg and body ~= "0" then v = -v; body = "-" .. body end
  return {value = v, num = (#body <= 15) and tonumber(body) or nil, text = body}
end

local TEXT_REFUSALS = {
  "robot%s*err%s*code%s*[:=]%s*(%-?%d+)", "robot%s*error%s*code%s*[:=]%s*(%-?%d+)",
}

-- How a reply refuses, as conformance/validate.py classify_reply reads it (without the
-- request: REPLIES says what the ID's commands reply): nil, or {form = "text" | "zero" |
-- "errcode", code = code_of(...) or nil (a code too long to be one)}.
local function refusal_of(cmd_id, data)
  local low, best, digits = data:lower(), nil, nil
  for _, pat in ipairs(TEXT_REFUSALS) do
    local at, _, d = low:find(pat)
    if at and (not best or at < best) then best, digits = at, d end
  end
  if best then return {form = "text", code = code_of(digits)} end
  local kind = REPLIES[cmd_id]
  if kind == nil and not NAMES[cmd_id] and not DIALECTS[cmd_id] then kind = "e" end
  local lone = kind and data:match("^%s*([%+%-]?%d+)%s*$")
  if not lone then return nil end
  local code = code_of(lone)
  if code and code.text == "0" then return {form = "zero", code = code} end
  if kind == "e" then
    if code and code.text == "1" then return nil end
    return {form = "errcode", code = code}
  end
  if code and code.num and ERRORS[code.num] then return {form = "errcode", code = code} end
  return nil
end

local function add_refusal(item, r, data_range)
  local ri = item:add(pf.refused, data_range, true)
  ri:set_generated()
  local c = r.code
  if not c then
    ri:add_proto_expert_info(ef.refused, "Refused (the code is too long to be one)")
    return "refused"
  end
  item:add(pf.errcode, data_range, c.value):set_generated()
  local e = c.num and ERRORS[c.num]
  local what
  if r.form == "zero" then
    what = "0 where 1 is success"
  elseif e then
    item:add(pf.errcode_meaning, data_range, e[1]):set_generated()
    if e[2] then item:add(pf.errcode_meaning_en, data_range, e[2]):set_generated() end
    what = e[2] and (e[2] .. " / " .. e[1]) or e[1]
  else
    what = "not in chapter 9's table"
  end
  local text = "refused, code " .. c.text .. " (" .. what .. ")"
  ri:add_proto_expert_info(ef.refused, "Refused: code " .. c.text .. " (" .. what .. ")")
  return text
end

local function add_frame(tvb, pinfo, tree, base, f, dir)
  -- base: tvb offset of s[1]; dir: "request", "reply" or nil (the ports do not say)
  local function rng(from, count) return tvb(base + from - 1, count) end
  local first = f.first
  local item = tree:add(fairino, rng(first, f.stop - first + 1))
  item:add(pf.cnt, rng(f.cnt[1], f.cnt[2]), UInt64.new(f.cnt_v))
  item:add(pf.cmd_id, rng(f.cmd_id[1], f.cmd_id[2]), UInt64.new(f.cmd_id_v))
  local data_range = (f.de > f.ds) and rng(f.ds, f.de - f.ds) or rng(f.ds, 0)
  local data = (f.de > f.ds) and data_range:string(ENC_UTF_8) or ""
  -- A call: a name and its argument list, or a keyword alone (STOP); "robot errcode:14"
  -- is no call, nor is "V3.8.2".  Where the ports do not say, a call is a request.
  local call = data:match("^%s*([A-Za-z_][A-Za-z0-9_]*)%s*%(")
  if call and not dir then dir = "request" end
  call = call or data:match("^%s*([A-Za-z_][A-Za-z0-9_]*)%s*$")
  local refusal = (dir ~= "request") and refusal_of(f.cmd_id_v, data) or nil
  if refusal then call = nil end
  local name, names = name_of(f.cmd_id_v, call)
  local ni = item:add(pf.name, rng(f.cmd_id[1], f.cmd_id[2]), name)
  if names and #names > 1 then
    item:add(pf.names, rng(f.cmd_id[1], f.cmd_id[2]), table.concat(names, " / "))
  end
  local d = DIALECTS[f.cmd_id_v]
  if d then
    item:add(pf.dialect, rng(f.cmd_id[1], f.cmd_id[2]), d.label)
    if d.only then ni:add_proto_expert_info(ef.dialect_id, "Command ID " .. f.cmd_id_v .. " is not in the manual; field dialect: " .. d.label) end
  end
  local li = item:add(pf.len, rng(f.len[1], f.len[2]), UInt64.new(f.len_v))
  item:add(pf.data, data_range, data)
  item:add(pf.data_len, data_range, f.de - f.ds)
  if call then item:add(pf.call, rng(f.ds + #data:match("^%s*"), #call), call) end
  local refused_text = refusal and add_refusal(item, refusal, data_range)
  if f.len_mismatch then
    local mi = item:add(pf.len_mismatch, rng(f.len[1], f.len[2]), true)
    mi:set_generated()
    li:add_proto_expert_info(ef.len_mismatch, "LEN " .. f.len_v .. ", DATA is " .. (f.de - f.ds) .. " bytes")
  end
  if f.bad_sep then
    item:add(pf.bad_separator, rng(first, f.stop - first + 1), true):set_generated()
    item:add_proto_expert_info(ef.bad_separator)
  end
  if not NAMES[f.cmd_id_v] and not d then
    item:add(pf.unknown_id, rng(f.cmd_id[1], f.cmd_id[2]), true):set_generated()
    ni:add_proto_expert_info(ef.unknown_id, "Command ID " .. f.cmd_id_v .. " is not in the specs")
  end
  local label = (name ~= "" and name or "?")
  item:append_text(", CNT " .. f.cnt_v .. ", ID " .. f.cmd_id_v .. " (" .. label .. "), LEN " .. f.len_v)
  local info = "CNT=" .. f.cnt_v .. " ID=" .. f.cmd_id_v .. " " .. label
  if refused_text then
    item:append_text(", " .. refused_text)
    info = info .. " " .. refused_text
  end
  return info
end

local function add_skipped(tvb, tree, base, from, stop, why)
  local r = tvb(base + from - 1, stop - from + 1)
  local item = tree:add(fairino, r)
  local si = item:add(pf.skipped, r)
  local s = r:raw()
  if s:match("^%z+$") then
    item:append_text(", " .. #s .. " NUL bytes")
    si:add_proto_expert_info(ef.padding, #s .. " NUL bytes")
  else
    item:append_text(", " .. #s .. " skipped bytes (" .. why .. ")")
    si:add_proto_expert_info(ef.garbage, #s .. " bytes skipped: " .. why)
  end
end

local function prefix_overlap(s, from)
  for k = 3, 1, -1 do
    if #s - from + 1 >= k and s:sub(#s - k + 1) == ("/f/b"):sub(1, k) then return k end
  end
  return 0
end

local registered = {tcp = {}, udp = {}}

local function direction_of(pinfo, is_tcp)
  -- A frame from a configured port is a reply, one to it a request; elsewhere (the
  -- heuristic dissector's flows) the content alone decides.
  local ports = is_tcp and registered.tcp or registered.udp
  local from, to = ports[pinfo.src_port], ports[pinfo.dst_port]
  if from and not to then return "reply" end
  if to and not from then return "request" end
  return nil
end

function fairino.dissector(tvb, pinfo, tree)
  local total = tvb:len()
  if total == 0 then return 0 end
  local is_tcp = pinfo.port_type == 2 -- PT_TCP
  local s = tvb:raw()
  local i = 1
  -- Read first, show after: a reassembled buffer that ends inside a frame is not shown.
  local items = {}
  local more_at, more_need = nil, nil
  while i <= total do
    local head = s:find("/f/b", i, true)
    if not head then
      local keep = is_tcp and prefix_overlap(s, i) or 0
      if total - keep >= i then items[#items + 1] = {i, total - keep, "not a frame"} end
      if keep > 0 then more_at = total - keep + 1 end
      break
    end
    if head > i then items[#items + 1] = {i, head - 1, "not a frame"} end
    local f = read_frame(s, head, not is_tcp)
    if f.kind == "more" then
      if is_tcp then
        more_at, more_need = head, f.need
      else
        items[#items + 1] = {head, total, "datagram ends inside a frame"}
      end
      break
    elseif f.kind == "skip" then
      items[#items + 1] = {head, f.stop, f.why}
      i = f.stop + 1
    else
      f.first = head
      items[#items + 1] = f
      i = f.stop + 1
    end
  end
  if more_at then
    -- A reassembled buffer (a tvb of its own: offset 0, where a segment's payload sits
    -- after the headers) ends inside a frame.  Its first bytes then came from earlier
    -- segments, and TCP would dissect it again from its start once extended
    -- (packet-tcp.c: the next PDU begins within the old fragments): show nothing now
    -- and ask for the extension, so that each frame is shown once, also on a second pass.
    if tvb:offset() == 0 and more_at > 1 then
      pinfo.desegment_offset = 0
      pinfo.desegment_len = more_need or DESEGMENT_ONE_MORE_SEGMENT
      return total
    end
    pinfo.desegment_offset = more_at - 1
    pinfo.desegment_len = more_need or DESEGMENT_ONE_MORE_SEGMENT
  end
  local infos = {}
  local dir = direction_of(pinfo, is_tcp)
  for _, it in ipairs(items) do
    if it.kind == "frame" then
      infos[#infos + 1] = add_frame(tvb, pinfo, tree, 0, it, dir)
    else
      add_skipped(tvb, tree, 0, it[1], it[2], it[3])
    end
  end
  if #infos > 0 then
    pinfo.cols.protocol = "FAIRINO"
    pinfo.cols.info = table.concat(infos, "; ")
  end
  return total
end

local function register_ports()
  local tcp_table = DissectorTable.get("tcp.port")
  local udp_table = DissectorTable.get("udp.port")
  for p in pairs(registered.tcp) do tcp_table:remove(p, fairino) end
  for p in pairs(registered.udp) do udp_table:remove(p, fairino) end
  registered.tcp, registered.udp = {}, {}
  local function each(range, fn)
    for part in tostring(range):gmatch("[^,]+") do
      local a, b = part:match("^%s*(%d+)%s*%-%s*(%d+)%s*$")
      if not a then a = part:match("^%s*(%d+)%s*$"); b = a end
      if a then for p = tonumber(a), tonumber(b) do fn(p) end end
    end
  end
  each(fairino.prefs.tcp_ports, function(p) tcp_table:add(p, fairino); registered.tcp[p] = true end)
  each(fairino.prefs.udp_ports, function(p) udp_table:add(p, fairino); registered.udp[p] = true end)
end

function fairino.prefs_changed() register_ports() end
register_ports()

-- The heuristic dissector: a TCP or UDP payload on any port that starts with a frame's
-- head and first separator (1.1, table 1-1-1).  On TCP the conversation is then FAIRINO
-- in both directions, so that segments starting inside a frame are read too.
local HEAD = "/f/bIII"
local function heuristic(tvb, pinfo, tree)
  if not fairino.prefs.heuristic then return false end
  if tvb:len() < #HEAD or tvb(0, #HEAD):raw() ~= HEAD then return false end
  if pinfo.port_type == 2 then pinfo.conversation = fairino end -- PT_TCP
  fairino.dissector(tvb, pinfo, tree)
  return true
end
fairino:register_heuristic("tcp", heuristic)
fairino:register_heuristic("udp", heuristic)
"""
