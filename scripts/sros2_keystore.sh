#!/usr/bin/env bash
# An SROS2-layout keystore made with openssl alone (no ROS install): one CA for identity and
# permissions, a signed governance that admits only authenticated participants and encrypts
# discovery, liveliness and data, and one enclave per ENCLAVE argument with its identity and
# signed permissions.
#
#   scripts/sros2_keystore.sh KEYSTORE ENCLAVE[:PUBLISH[:SUBSCRIBE]] ...
#
# PUBLISH and SUBSCRIBE are comma-separated DDS topic names or patterns (ROS topic /imu/data_raw
# is DDS topic rt/imu/data_raw; a service ~/adapt of node imu_fsda is rq/imu_fsda/adaptRequest
# and rr/imu_fsda/adaptReply); an empty list gives no rule of that kind.
# The layout is rcl's: KEYSTORE/enclaves/<enclave>/{identity_ca.cert.pem, cert.pem, key.pem,
# permissions_ca.cert.pem, governance.p7s, permissions.p7s}, the CA under KEYSTORE/public and
# KEYSTORE/private. Running it again adds enclaves to the same CA.
#
# The governance is `ros2 security`'s: RTPS messages, discovery, liveliness and each topic's
# submessages encrypted (metadata_protection_kind ENCRYPT: the whole DATA submessage, payload
# included) and the payload encrypted again (data_protection_kind ENCRYPT). An enclave given
# alone gets what `ros2 security create_enclave` grants without a policy: every ROS topic,
# service and action (rt/*, rq/*Request, rr/*Reply, …) and ros_discovery_info, in two rules.
# SROS2_DATA_PROTECTION=NONE drops that second layer (docs/interop.md, "Security", says why a
# Fast DDS service client needs it with this node).
set -euo pipefail
[ $# -ge 2 ] || { sed -n 2,22p "$0"; exit 2; }
keystore="$1"; shift
case "${SROS2_DATA_PROTECTION:-ENCRYPT}" in ENCRYPT|SIGN|NONE) ;; *) echo "sros2_keystore: SROS2_DATA_PROTECTION is ENCRYPT, SIGN or NONE" >&2; exit 2;; esac
command -v openssl >/dev/null || { echo "sros2_keystore: openssl is needed" >&2; exit 1; }
mkdir -p "$keystore/public" "$keystore/private" "$keystore/enclaves"
ca_key="$keystore/private/ca.key.pem"
ca_cert="$keystore/public/ca.cert.pem"
if [ ! -f "$ca_key" ]; then
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$ca_key" 2>/dev/null
  openssl req -x509 -new -key "$ca_key" -out "$ca_cert" -days 3650 -sha256 -subj "/CN=sros2testCA" 2>/dev/null
  ln -sf ca.cert.pem "$keystore/public/identity_ca.cert.pem"
  ln -sf ca.cert.pem "$keystore/public/permissions_ca.cert.pem"
  ln -sf ca.key.pem "$keystore/private/identity_ca.key.pem"
  ln -sf ca.key.pem "$keystore/private/permissions_ca.key.pem"
fi

sign() { # an S/MIME signature by the permissions CA, as the DDS Security spec reads it
  openssl smime -sign -text -in "$1" -out "$2" -signer "$ca_cert" -inkey "$ca_key" 2>/dev/null
}

# Every domain a ROS_DOMAIN_ID may name that Cyclone DDS also accepts (it refuses 231–232).
domains='<domains><id_range><min>0</min><max>230</max></id_range></domains>'
# What `ros2 security create_enclave` grants without a policy: every ROS topic, service, action.
ros_topics='rt/*,rq/*Request,rr/*Reply,rq/*/_action/cancel_goalRequest,rq/*/_action/get_resultRequest,rq/*/_action/send_goalRequest,rr/*/_action/cancel_goalReply,rr/*/_action/get_resultReply,rr/*/_action/send_goalReply,rt/*/_action/feedback,rt/*/_action/status'

governance="$keystore/enclaves/governance.xml"
if [ ! -f "$keystore/enclaves/governance.p7s" ]; then
  cat >"$governance" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      ${domains}
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>${SROS2_DATA_PROTECTION:-ENCRYPT}</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
XML
  sign "$governance" "$keystore/enclaves/governance.p7s"
fi

topics_xml() { # "a,b" → <topic>a</topic><topic>b</topic>; a pattern is written, not expanded
  local IFS=, t
  read -ra list <<<"$1"
  for t in "${list[@]}"; do printf '<topic>%s</topic>' "$t"; done
}

for spec in "$@"; do
  IFS=: read -r enclave publish subscribe <<<"$spec"
  [ "${enclave:0:1}" = / ] || { echo "sros2_keystore: an enclave is an absolute name (/imu_fsda), not $enclave" >&2; exit 2; }
  [ "$spec" = "$enclave" ] && { publish="$ros_topics"; subscribe="$ros_topics"; }
  dir="$keystore/enclaves${enclave}"
  mkdir -p "$dir"
  # PKCS#8, as sros2 writes it (RustDDS reads no other form)
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$dir/key.pem" 2>/dev/null
  openssl req -new -key "$dir/key.pem" -out "$dir/req.pem" -subj "/CN=${enclave//\//\\/}" 2>/dev/null
  openssl x509 -req -in "$dir/req.pem" -CA "$ca_cert" -CAkey "$ca_key" -CAcreateserial \
    -out "$dir/cert.pem" -days 3650 -sha256 2>/dev/null
  rm -f "$dir/req.pem"
  cp "$ca_cert" "$dir/identity_ca.cert.pem"
  cp "$ca_cert" "$dir/permissions_ca.cert.pem"
  cp "$keystore/enclaves/governance.p7s" "$dir/governance.p7s"
  subject="$(openssl x509 -in "$dir/cert.pem" -noout -subject -nameopt RFC2253 | sed 's/^subject=//')"
  rules=""
  [ -n "$publish" ] && rules+="<publish><topics>$(topics_xml "$publish")</topics></publish>"
  [ -n "$subscribe" ] && rules+="<subscribe><topics>$(topics_xml "$subscribe")</topics></subscribe>"
  cat >"$dir/permissions.xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="${enclave}">
      <subject_name>${subject}</subject_name>
      <validity><not_before>2020-01-01T00:00:00</not_before><not_after>2036-01-01T00:00:00</not_after></validity>
      <allow_rule>
        ${domains}
        ${rules}
      </allow_rule>
      <allow_rule>
        ${domains}
        <publish><topics><topic>ros_discovery_info</topic></topics></publish>
        <subscribe><topics><topic>ros_discovery_info</topic></topics></subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
XML
  sign "$dir/permissions.xml" "$dir/permissions.p7s"
  echo "$dir"
done
